"""The paper's experiments, behaviours and pictures."""
