"""The Duckiebot (Duckietown's differential-drive robot with one camera), issue 23, first layer.

- `robot`: the DB21 / DB18 description (wheels, encoders, camera prior and mount) and Duckietown's kinematics
  parameters;
- `kinematics`: Duckietown's forward and inverse kinematics, its duty-to-PWM map, pose integration;
- `drive_log`: the strict reader of a drive log (`naocal.drive_log/1`);
- `calibration_files`: Duckietown's three calibration files (writer and strict reader, plausibility checks);
- `detect`: AprilTag 36h11 markers (OpenCV's class API) and chessboards (agent.board_detect);
- `intrinsics`: the camera's intrinsics, the lens model chosen by held-out reprojection error;
- `render`: an independent OpenCV renderer of the calibration set-up writing a drive log.

Not wired into the CLI yet (the dispatch is being redesigned, issue 22): each module exposes plain functions.
Facts and numbers come from docs/DUCKIEBOT.md, which cites their public sources.
"""
