"""The layered MDP: the grid, the actions and the tables the kernels read (Section V)."""
