"""Modbus TCP and RTU driver: register maps as data (presets/), a motion handshake with a robot program."""
