"""The solved strategy, its file format and its execution rules."""
