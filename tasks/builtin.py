"""Imports every built-in task module so each registers itself."""
