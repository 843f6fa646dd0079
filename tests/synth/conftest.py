"""The synth tests use the session-wide ``tiny_mission`` / ``tiny_mission_path`` of tests/conftest.py."""
