"""GRBL 1.1 over serial: wire protocol (pure parsers), driver, protocol peer, passthrough.

Only this package imports pyserial (and only ``driver`` and ``passthrough`` do).
"""
