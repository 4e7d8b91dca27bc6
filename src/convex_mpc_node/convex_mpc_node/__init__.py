"""Phase integrator, convex MPC stance control and swing control: library core and node."""
