"""GLSL -> OSL for the subset of GLSL that ``glsl/btf_core.glsl`` is written in.

The shading has one hand-written source, the GLSL core.  OSL (Cycles, Arnold, RenderMan, the
MaterialX ``genosl`` target) gets the same functions from it mechanically: :func:`translate`
rewrites the text, and ``glsl/osl_glsl_types.h`` supplies GLSL's types and built-ins in OSL
(structs with overloaded operators).  The subset, and what each construct becomes:

========================================  =====================================================
GLSL                                      OSL
========================================  =====================================================
``vec3``, ``sampler2D``                   ``vector``, ``string`` (a texture is its file name)
``vec2 vec4 ivec2 ivec3 ivec4 mat3``      the structs ``btfVec2`` .. ``btfMat3``
``T(args)`` (a constructor or cast)       ``btfMakeT(args)`` (overloaded in the header)
``e.xy`` (2-4 letter swizzle)             ``btf_xy(e)``
``v[i]`` read                             ``btfAt(v, i)`` (a write ``v[i] = ...`` stays: vec3)
``a += b`` (any ``op=``)                  ``a = a + (b)``
``out`` parameter                         ``output`` parameter
``atan(y, x)``                            ``atan2(y, x)``
``texelFetch``, ``textureSize``           ``btfTexelFetch``, ``btfTextureSize`` (closest texel)
identifiers OSL reserves (``v``, ...)     the same with a trailing ``_``
========================================  =====================================================

Anything outside the subset (block comments, arrays, ``inout``, ``?:`` on struct types, a
swizzle or index written to) is refused with :class:`TranslationError` naming the line, or
fails OSL's compiler; the tests compile the result with Cycles' OSL compiler and render it.
"""
from __future__ import annotations

import re

__all__ = ["TranslationError", "translate", "STRUCT_TYPES"]

#: GLSL types that become the header's structs.
STRUCT_TYPES = {"vec2": "btfVec2", "vec4": "btfVec4", "ivec2": "btfIVec2", "ivec3": "btfIVec3",
                "ivec4": "btfIVec4", "mat3": "btfMat3"}
_CONSTRUCTORS = {**{glsl: "btfMake" + osl[3:] for glsl, osl in STRUCT_TYPES.items()}, "vec3": "btfMakeVec3"}
_RENAMED_CALLS = {"texelFetch": "btfTexelFetch", "textureSize": "btfTextureSize"}
#: OSL keywords, types and shader globals a GLSL identifier may collide with.
_OSL_RESERVED = {"closure", "color", "matrix", "normal", "output", "point", "public", "shader", "string", "struct",
                 "surface", "vector", "volume", "displacement", "emission", "u", "v", "N", "Ng", "P", "I", "Ci",
                 "dPdu", "dPdv", "Ps", "time", "dtime", "dPdtime", "illuminance", "illuminate", "light"}
_UNSUPPORTED = [(re.compile(r"/\*"), "block comment"), (re.compile(r"\binout\b"), "inout parameter"),
                (re.compile(r"\b(?:vec[234]|ivec[234]|mat3|float|int)\s+\w+\s*\["), "array")]
_IDENT = re.compile(r"[A-Za-z_]\w*")


class TranslationError(ValueError):
    """The GLSL uses a construct outside the translated subset."""


def _split_comments(text: str) -> tuple[str, list[str]]:
    """The code with every ``//`` comment replaced by a placeholder, and the comments."""
    comments: list[str] = []

    def keep(match):
        comments.append(match.group(0))
        return f"\x00{len(comments) - 1}\x00"

    return re.sub(r"//[^\n]*", keep, text), comments


def _join_comments(code: str, comments: list[str]) -> str:
    return re.sub(r"\x00(\d+)\x00", lambda m: comments[int(m.group(1))], code)


def _matching(code: str, start: int, opening: str, closing: str, step: int) -> int:
    """Index of the bracket matching the one at ``start``, scanning by ``step`` (+1 / -1)."""
    depth = 0
    i = start
    while 0 <= i < len(code):
        if code[i] == opening:
            depth += 1
        elif code[i] == closing:
            depth -= 1
            if depth == 0:
                return i
        i += step
    raise TranslationError(f"unbalanced {opening}{closing} near: {code[max(0, start - 40):start + 40]!r}")


def _operand_start(code: str, end: int) -> int:
    """Start of the postfix expression ending just before ``end``: an identifier, a call, a
    parenthesised expression, each with any number of [index] / (call) suffixes."""
    i = end
    while True:
        j = i - 1
        if j >= 0 and code[j] in ")]":
            j = _matching(code, j, code[j], "(" if code[j] == ")" else "[", -1)
            i = j
            continue
        match = re.search(r"[A-Za-z_]\w*$", code[:i])
        if match and (match.start() == i - len(match.group(0))):
            return match.start()
        return i


def _rewrite_swizzles(code: str) -> str:
    """``e.xy`` -> ``btf_xy(e)``; ``f(...).x`` -> ``btfAt(f(...), 0)`` (OSL reads a field of a
    variable, not of a call's result)."""
    pattern = re.compile(r"\.([xyzw]{2,4})\b|(?<=\))\.([xyzw])\b")
    while (match := pattern.search(code)) is not None:
        start = _operand_start(code, match.start())
        if start == match.start():
            raise TranslationError(f"swizzle {match.group(0)} of nothing near {code[start - 30:start + 10]!r}")
        if re.match(r"\s*=(?!=)", code[match.end():]):
            raise TranslationError(f"write to swizzle {match.group(0)}: not in the subset")
        operand = code[start:match.start()]
        new = (f"btf_{match.group(1)}({operand})" if match.group(1)
               else f"btfAt({operand}, {'xyzw'.index(match.group(2))})")
        code = code[:start] + new + code[match.end():]
    return code


def _rewrite_compound(code: str) -> str:
    """``a op= b;`` -> ``a = a op (b);`` (OSL has no compound assignment on structs)."""
    return re.sub(r"(?<![\w\]])([A-Za-z_]\w*(?:\[[^\]]*\])?)\s*([-+*/%])=\s*([^;]+);",
                  lambda m: f"{m.group(1)} = {m.group(1)} {m.group(2)} ({m.group(3)});", code)


def _rewrite_indexing(code: str) -> str:
    """Reads ``name[i]`` -> ``btfAt(name, i)``; writes ``name[i] = `` stay (native on vector)."""
    out, pos = [], 0
    for match in re.finditer(r"\b([A-Za-z_]\w*)\[", code):
        if match.start() < pos:
            continue
        close = _matching(code, match.end() - 1, "[", "]", 1)
        if re.match(r"\s*=(?!=)", code[close + 1:]):
            continue
        out.append(code[pos:match.start()])
        out.append(f"btfAt({match.group(1)}, {_rewrite_indexing(code[match.end():close])})")
        pos = close + 1
    out.append(code[pos:])
    return "".join(out)


def _rewrite_atan2(code: str) -> str:
    out, pos = [], 0
    for match in re.finditer(r"\batan\s*\(", code):
        close = _matching(code, match.end() - 1, "(", ")", 1)
        inner, depth = code[match.end():close], 0
        two = any((depth := depth + (c in "([") - (c in ")]")) == 0 and c == "," for c in inner)
        out.append(code[pos:match.start()] + ("atan2(" if two else "atan("))
        pos = match.end()
    out.append(code[pos:])
    return "".join(out)


def _rename(code: str) -> str:
    code = re.sub(r"(?<![.\w])(" + "|".join(sorted(_OSL_RESERVED)) + r")\b(?!\s*\()", r"\1_", code)
    code = re.sub(r"\b(" + "|".join(_CONSTRUCTORS) + r")\s*\(", lambda m: _CONSTRUCTORS[m.group(1)] + "(", code)
    code = re.sub(r"\b(" + "|".join(STRUCT_TYPES) + r")\b", lambda m: STRUCT_TYPES[m.group(1)], code)
    code = re.sub(r"\bvec3\b", "vector", code)
    code = re.sub(r"\bsampler2D\b", "string", code)
    code = re.sub(r"\bout\b", "output", code)
    return re.sub(r"\b(" + "|".join(_RENAMED_CALLS) + r")\s*\(", lambda m: _RENAMED_CALLS[m.group(1)] + "(", code)


def translate(glsl: str) -> str:
    """OSL text of the GLSL functions ``glsl`` (functions and #defines, no ``main``, no
    ``#version``), to be compiled after ``glsl/osl_glsl_types.h``.  Comments are kept."""
    code, comments = _split_comments(glsl)
    for number, line in enumerate(code.splitlines(), 1):
        for pattern, what in _UNSUPPORTED:
            if pattern.search(line):
                raise TranslationError(f"line {number}: {what} is outside the GLSL subset the OSL translation "
                                       f"takes: {line.strip()!r}")
    code = _rename(_rewrite_indexing(_rewrite_compound(_rewrite_atan2(_rewrite_swizzles(code)))))
    return _join_comments(code, comments)
