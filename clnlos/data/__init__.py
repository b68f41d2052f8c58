"""Built-in default scenes (package data)."""
