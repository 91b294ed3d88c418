"""The robot's body as shapes (PyBullet): collision checking for the agent's safety and planner, and the mock's
simulated body. Built from the nominal URDF; no robot connection."""
