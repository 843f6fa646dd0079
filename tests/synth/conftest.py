"""Synth tests use the session-wide ``tiny_mission_path`` / ``tiny_mission`` fixtures of tests/conftest.py."""
