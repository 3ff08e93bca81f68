"""Build tests: colcon and pip builds of the package, the kernels compiled at install."""
