"""The values of a space file: arithmetic strings such as "sqrt(3)/2", vectors, counts and texts,
each read or refused with a SpaceError naming where it is."""

from __future__ import annotations

import ast
import math
import operator

import numpy as np


class SpaceError(ValueError):
    """A space file that cannot be read or does not describe a valid space."""


# --- safe arithmetic for matrix entries such as "sqrt(3)/2" ------------------------------------
_FUNCS = {
    n: getattr(math, n)
    for n in (
        "sqrt",
        "sin",
        "cos",
        "tan",
        "asin",
        "acos",
        "atan",
        "sinh",
        "cosh",
        "tanh",
        "asinh",
        "acosh",
        "atanh",
        "exp",
        "log",
    )
}
_CONSTS = {"pi": math.pi, "phi": (1 + math.sqrt(5)) / 2, "e": math.e}
_OPS = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.Pow: operator.pow,
    ast.USub: operator.neg,
    ast.UAdd: operator.pos,
}


def quoted(value, longest: int = 80) -> str:
    """A value as an error quotes it: whole where short, else its start and its length (an 800 KB
    expression quoted whole buries the message)."""
    text = repr(value)
    return text if len(text) <= longest else f"{text[: longest - 20]}... ({len(text)} characters)"


def evaluate(value, where: str) -> float:
    """A number, or a string of arithmetic with sqrt, sin, ..., pi, phi."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if not isinstance(value, str):
        raise SpaceError(f"{where}: expected a number or an arithmetic string, got {quoted(value)}")

    def ev(node):
        if isinstance(node, ast.Expression):
            return ev(node.body)
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)):
            return float(node.value)
        if isinstance(node, ast.Name) and node.id in _CONSTS:
            return _CONSTS[node.id]
        if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
            return _OPS[type(node.op)](ev(node.left), ev(node.right))
        if isinstance(node, ast.UnaryOp) and type(node.op) in _OPS:
            return _OPS[type(node.op)](ev(node.operand))
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id in _FUNCS
            and len(node.args) == 1
        ):
            return _FUNCS[node.func.id](ev(node.args[0]))
        raise SpaceError(f"{where}: cannot evaluate {shown} (numbers, + - * / **, pi, phi, sqrt, sin, cos, ... only)")

    shown = quoted(value)
    try:
        result = ev(ast.parse(value, mode="eval"))
    except SpaceError:
        raise
    except SyntaxError:
        raise SpaceError(f"{where}: cannot evaluate {shown}: it is not an arithmetic expression") from None
    except (OverflowError, MemoryError, RecursionError):
        raise SpaceError(f"{where}: cannot evaluate {shown}: it is too large") from None
    except (ZeroDivisionError, ValueError, TypeError) as exc:  # division by zero, math domain error
        raise SpaceError(f"{where}: cannot evaluate {shown}: {exc}") from None
    if not isinstance(result, float) or not math.isfinite(result):
        raise SpaceError(f"{where}: cannot evaluate {shown}: not a finite real number")
    return result


def vector(value, n, where):
    if not isinstance(value, list) or len(value) != n:
        raise SpaceError(f"{where}: expected a list of {n} numbers, got {value!r}")
    return np.array([evaluate(v, f"{where}[{i}]") for i, v in enumerate(value)])


_INT32_MAX = 2**31 - 1  # the tracer's counters are 32-bit


def count(value, where) -> int:
    """A whole number >= 0 (an integral float such as 64.0 is accepted, 2.7 is not)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SpaceError(f"{where}: expected a whole number >= 0, got {value!r}")
    if isinstance(value, float) and not (math.isfinite(value) and value.is_integer()):
        raise SpaceError(f"{where}: expected a whole number >= 0, got {value!r}")
    if not 0 <= value <= _INT32_MAX:
        raise SpaceError(f"{where}: expected a whole number between 0 and {_INT32_MAX}, got {value!r}")
    return int(value)


def text(data: dict, key: str, default: str, where: str) -> str:
    value = data.get(key, default)
    if not isinstance(value, str):
        raise SpaceError(f"{where}: {key} must be a string, got {value!r}")
    return value
