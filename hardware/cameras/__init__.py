"""The Flea2 stereo pair on cv2.VideoCapture: driver and file-backed test sources."""
