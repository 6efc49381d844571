"""pyserial URL handlers of the tactile driver: importing the package registers `ppsemu://`."""

import serial

if __name__ not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append(__name__)
