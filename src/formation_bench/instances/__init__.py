"""The instance library: recorded local problems with best-known optima, and how it is built."""
