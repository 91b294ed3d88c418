"""naocal's solver: the robot description, the camera model, the measurement model and its effects (one module each
in solver/effects/), the parameter registry, identification and diagnostics. Pure computation: no robot, no I/O
except the robot description, dataset and offsets readers and writers."""
