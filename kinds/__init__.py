"""Robot kinds beside the NAO and the arm, each in its own package (issue 22 makes them plug-ins of one core)."""
