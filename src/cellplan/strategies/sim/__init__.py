"""The stochastic simulation of a strategy against request arrivals."""
