"""Simulated Modbus robot: a pymodbus server (TCP, or RTU over a pty pair) serving a register map from the physics core."""
