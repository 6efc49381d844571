"""Vision on stereo recordings: calibration, reconstruction, contours. Backend-free (architecture.md)."""
