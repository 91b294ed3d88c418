"""naocal's NAO model, parameter registry, identification and diagnostics. Pure computation: no robot, no I/O
except the dataset and offsets readers and writers."""
