"""The runners and what a user meets: the command line, the simulated and wall clocks, the
two-process run, the keyboard, metrics, recorders, plots, progress and sweeps. Everything here
composes the sides of :mod:`teleop.tick` through :mod:`teleop.app.assembly`."""
