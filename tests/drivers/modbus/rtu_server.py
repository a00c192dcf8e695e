"""The virtual server speaking Modbus RTU framing over TCP, reached by the driver through
pyserial's ``socket://`` URL, and behaving like an RTU slave on a serial line: one request
at a time (half duplex); a "late" answer carries the registers sampled when its request
came and is sent ``late_s`` later; :meth:`RtuOverTcpServer.corrupt` flips the CRC of the
next answers (noise on the line)."""

from __future__ import annotations

import asyncio

from pymodbus.framer import FramerType

from drivers.modbus.server import ModbusVirtualServer, _InOrderTcpServer, _MachineContext


class RtuOverTcpServer(ModbusVirtualServer):
    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self._corrupt = 0
        #: answers sent with a bad CRC so far
        self.corrupted = 0

    def url(self, **q) -> str:
        query = "&".join(f"{k}={v}" for k, v in {"baud": 115200, **q}.items())
        return f"modbus+rtu://socket://127.0.0.1:{self.port}?{query}"

    def corrupt(self, n: int = 1) -> None:
        """Send the next ``n`` answers with their CRC's low byte flipped."""
        self._corrupt += n

    async def _serve(self):
        self._seq = asyncio.Lock()
        port = self.port if self.port is not None else self.requested_port
        self._server = _InOrderTcpServer(_MachineContext(self), address=(self.host, port), framer=FramerType.RTU,
                                         broadcast_enable=True, ignore_missing_devices=True,
                                         trace_packet=self._trace_packet, trace_pdu=self._trace_pdu)
        await self._server.serve_forever(background=True)
        self.port = self._server.transport.sockets[0].getsockname()[1]
        self._ready.set()

    def _trace_packet(self, sending: bool, packet: bytes) -> bytes:
        packet = super()._trace_packet(sending, packet)
        if sending and self._corrupt > 0:
            self._corrupt -= 1
            self.corrupted += 1
            packet = packet[:-1] + bytes([packet[-1] ^ 0xFF])
        return packet

    async def _answer(self, unit, func_code, address, count, values):
        async with self._seq:  # half duplex: the next request waits for this answer
            return await super()._answer(unit, func_code, address, count, values)

    async def _read_with_faults(self, unit, func_code, address, count):
        fault = self._next_fault()
        if fault == "late":
            answer = self._read(unit, func_code, address, count)  # sampled now ...
            self.faults_done[fault] += 1
            await asyncio.sleep(self.late_s)                       # ... sent late
            return answer
        self._script.appendleft(fault)
        return await super()._read_with_faults(unit, func_code, address, count)
