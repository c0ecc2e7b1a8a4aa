"""Dynamixel Protocol 2.0 layer: units, control tables, codec, emulator and driver."""
