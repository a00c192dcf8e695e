"""Modbus CNC controllers (the only package that imports pymodbus): register maps,
the polling driver and the server peer that exposes the virtual machine."""
