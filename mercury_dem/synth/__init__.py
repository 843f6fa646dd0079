"""The synthetic Mercury: procedural surface, MDIS-like cameras, rendered images, perturbed pointing (docs/design/synth.md)."""
