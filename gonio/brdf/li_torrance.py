"""Placeholder: this family is being written (see issue 2)."""
