"""The solvers: value iteration sweeps, policy iteration and their compiled kernels."""
