"""The adaptive package."""
