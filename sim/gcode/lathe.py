"""The lathe-only G codes of LinuxCNC, which dexmon (a mill simulator) refuses clearly."""

from __future__ import annotations

#: code (in tenths) -> what it is on a lathe
LATHE_G = {
    70: "diameter mode", 80: "radius mode",
    700: "finishing cycle", 710: "roughing cycle", 711: "roughing cycle", 712: "roughing cycle",
    720: "facing cycle", 721: "facing cycle", 722: "facing cycle",
    760: "threading cycle",
}


def lathe_message(code10: int) -> str | None:
    """Why G<code10/10> is refused, when it is a lathe-only code (else None)."""
    what = LATHE_G.get(code10)
    if what is None:
        return None
    return f"G{code10 / 10:g} is a lathe-only {what}: dexmon simulates mills"
