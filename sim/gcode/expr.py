"""Evaluate RS274NGC expression trees built by :mod:`sim.gcode.parser`.

Angles are degrees, as in LinuxCNC. Comparison and logic operators give 1.0 / 0.0.
LinuxCNC compares with a tolerance (``TOLERANCE_EQUAL``) for EQ/NE.
"""

from __future__ import annotations

import math

from sim.gcode.errors import LineError

TOLERANCE_EQUAL = 0.0001  # LinuxCNC: two numbers compare EQ if closer than this


def _fn(name: str, x: float) -> float:
    if name == "ABS":
        return abs(x)
    if name == "ACOS":
        if not -1.0 <= x <= 1.0:
            raise LineError(f"ACOS argument {x:g} is out of range [-1, 1]")
        return math.degrees(math.acos(x))
    if name == "ASIN":
        if not -1.0 <= x <= 1.0:
            raise LineError(f"ASIN argument {x:g} is out of range [-1, 1]")
        return math.degrees(math.asin(x))
    if name == "COS":
        return math.cos(math.radians(x))
    if name == "SIN":
        return math.sin(math.radians(x))
    if name == "TAN":
        return math.tan(math.radians(x))
    if name == "EXP":
        try:
            return math.exp(x)
        except OverflowError:
            raise LineError(f"EXP[{x:g}] overflows") from None
    if name == "LN":
        if x <= 0.0:
            raise LineError(f"LN argument {x:g} must be positive")
        return math.log(x)
    if name == "SQRT":
        if x < 0.0:
            raise LineError(f"SQRT argument {x:g} is negative")
        return math.sqrt(x)
    if name == "FIX":
        return float(math.floor(x))
    if name == "FUP":
        return float(math.ceil(x))
    if name == "ROUND":
        # RS274NGC rounds half away from zero
        return float(math.floor(x + 0.5)) if x >= 0 else -float(math.floor(-x + 0.5))
    raise LineError(f"unknown function {name}")


def _mod(a: float, b: float) -> float:
    """``a MOD b`` as rs274 computes it (interp_execute.cc ``execute_binary1``): C's fmod,
    then a negative result made non-negative by adding ``|b|`` whatever b's sign
    (-7 MOD -3 is 2, 7 MOD -3 is 1). fmod is exact, so the result is in [0, |b|)
    but for a tiny negative remainder, where adding |b| rounds to |b| as in C."""
    r = math.fmod(a, b)
    return r + abs(b) if r < 0.0 else r


def _binary(op: str, a: float, b: float) -> float:
    if op == "+":
        return a + b
    if op == "-":
        return a - b
    if op == "*":
        return a * b
    if op == "/":
        if b == 0.0:
            raise LineError("division by zero in expression")
        return a / b
    if op == "MOD":
        if b == 0.0:
            raise LineError("MOD by zero in expression")
        return _mod(a, b)
    if op == "**":
        if a < 0.0 and b != math.floor(b):
            raise LineError(f"{a:g} ** {b:g}: negative base with a non-integer exponent")
        try:
            return float(a**b)
        except (OverflowError, ZeroDivisionError):
            raise LineError(f"{a:g} ** {b:g} cannot be computed") from None
    if op == "EQ":
        return 1.0 if abs(a - b) < TOLERANCE_EQUAL else 0.0
    if op == "NE":
        return 0.0 if abs(a - b) < TOLERANCE_EQUAL else 1.0
    if op == "GT":
        return 1.0 if a > b else 0.0
    if op == "GE":
        return 1.0 if a >= b else 0.0
    if op == "LT":
        return 1.0 if a < b else 0.0
    if op == "LE":
        return 1.0 if a <= b else 0.0
    if op == "AND":
        return 1.0 if (a != 0.0 and b != 0.0) else 0.0
    if op == "OR":
        return 1.0 if (a != 0.0 or b != 0.0) else 0.0
    if op == "XOR":
        return 1.0 if ((a != 0.0) != (b != 0.0)) else 0.0
    raise LineError(f"unknown operator {op}")


def evaluate(tree, params) -> float:
    """Value of ``tree``; ``params`` has ``get_numbered(i)``, ``get_named(name)``, ``exists(name)``."""
    if type(tree) is float:
        return tree
    tag = tree[0]
    if tag == "b":
        # a flat chain (``1+1+...+1``) is a left spine as long as the chain: walk it
        # without recursing, so its length is bounded by the line, not by the stack
        spine = []
        while type(tree) is not float and tree[0] == "b":
            spine.append(tree)
            tree = tree[2]
        v = evaluate(tree, params)
        for node in reversed(spine):
            v = _binary(node[1], v, evaluate(node[3], params))
            if not math.isfinite(v):
                raise LineError("expression result is not a finite number")
        return v
    elif tag == "p":
        idx = evaluate(tree[1], params)
        v = params.get_numbered(idx)
    elif tag == "n":
        v = params.get_named(tree[1])
    elif tag == "f":
        v = _fn(tree[1], evaluate(tree[2], params))
    elif tag == "neg":
        v = -evaluate(tree[1], params)
    elif tag == "atan":
        v = math.degrees(math.atan2(evaluate(tree[1], params), evaluate(tree[2], params)))
    elif tag == "exists":
        v = 1.0 if params.exists(tree[1]) else 0.0
    else:  # pragma: no cover - parser never builds other tags
        raise LineError(f"bad expression node {tag!r}")
    if not math.isfinite(v):
        raise LineError("expression result is not a finite number")
    return v
