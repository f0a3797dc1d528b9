"""The cell's PLC in charge: `payload-agent serve` over OPC UA (asyncua) and Modbus registers (pymodbus)."""
