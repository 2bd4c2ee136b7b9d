"""Camera calibration: intrinsics and distortion from chessboard views (``chessboard``) or from views of
livetrack ring targets with exposure-bias compensation (``targets``). Pure functions on arrays, no I/O; the
``livetrack calibrate`` command (``livetrack.commands.calibrate``) reads the images and writes the files."""
