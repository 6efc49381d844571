"""pyserial URL handlers of this project: importing the package registers `bh8emu://`."""

import serial

if __name__ not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append(__name__)
