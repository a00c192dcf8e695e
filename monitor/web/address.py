"""Where the browser view listens: ``HOST:PORT``, ``:PORT``, ``PORT`` or ``HOST``."""

from __future__ import annotations

import ipaddress

from sim.errors import InputError

#: the default: this computer only, a free port chosen by the system
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 0


def parse_address(text: str | None, where: str = "--address") -> tuple[str, int]:
    """``(host, port)`` from ``text`` (None or "": the defaults); InputError naming
    ``where`` for a port that is not 0..65535."""
    s = (text or "").strip()
    if not s:
        return DEFAULT_HOST, DEFAULT_PORT
    if s.startswith("["):  # [::1]:8080
        host, _, rest = s[1:].partition("]")
        port_text = rest.removeprefix(":")
    elif s.count(":") == 1:
        host, _, port_text = s.partition(":")
    elif s.isdigit():
        host, port_text = "", s
    else:  # a host alone (IPv6 without brackets too)
        host, port_text = s, ""
    host = host or DEFAULT_HOST
    if not port_text:
        return host, DEFAULT_PORT
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise InputError(f"expected HOST:PORT with a port 0..65535, got {text!r}", where)
    return host, int(port_text)


def is_loopback(host: str) -> bool:
    """True when only this computer can reach ``host`` (127.x, ::1, localhost)."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def exposure_warning(host: str, port: int) -> str | None:
    """The warning for listening where other computers can reach the page, or None."""
    if is_loopback(host):
        return None
    return (f"the browser view listens on {host}:{port}: anyone who can reach this computer there "
            "can watch the run (the page has no password)")


def url(host: str, port: int) -> str:
    """The page's address for a browser (a wildcard host is shown as this computer's loopback)."""
    shown = {"0.0.0.0": "127.0.0.1", "::": "[::1]", "": "127.0.0.1"}.get(host, host)
    if ":" in shown and not shown.startswith("["):
        shown = f"[{shown}]"
    return f"http://{shown}:{port}/"
