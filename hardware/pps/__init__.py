"""The PPS RoboTouch tactile pads: frame format (assumed), driver and emulator."""
