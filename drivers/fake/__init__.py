"""Fake devices speaking the real protocols on top of a simulated bench."""
