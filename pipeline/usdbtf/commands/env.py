"""``usdbtf env``: the environment any USD process needs to know the usdBtf plugin."""
from __future__ import annotations

import shlex

ORDER = 95


def add_parser(sub) -> None:
    p = sub.add_parser("env", help="print the shell lines that make any USD process know the usdBtf plugin "
                       "(schema, Sdr shader definition, MaterialX nodedefs)")
    p.add_argument("--json", action="store_true",
                   help="print {variable: [entries], separator: {...}} as JSON instead of shell lines")
    p.set_defaults(func=run)


def shell_lines() -> list[str]:
    """POSIX sh lines: each variable gets usdbtf's entries in front of whatever it holds."""
    from .. import __version__
    from ..usd.plugin import QUIET, defaults, environment, list_separator

    lines = [f"# usdbtf {__version__}: the usdBtf USD plugin for any USD process (eval in a launcher);",
             "# PXR_SDR_* for USD >= 25.05, PXR_NDR_* for USD 24.x-25.02 (each build reads its own)"]
    for variable, entries in environment().items():
        sep = list_separator(variable)
        value = shlex.quote(sep.join(entries))
        lines.append(f'export {variable}={value}"${{{variable}:+{sep}${variable}}}"')
    lines.append(f"# {QUIET}=0: no 'is overridden' banner from USD for these settings (a value set before wins)")
    for variable, value in defaults().items():
        lines.append(f'export {variable}="${{{variable}:-{shlex.quote(value)}}}"')
    return lines + numeric_lines()


def numeric_lines() -> list[str]:
    """The variables that pin the numeric platform (:mod:`usdbtf.numeric`), each unless the
    shell sets it already: every process of a build or a Dask cluster started with them
    writes the same bytes.  None on a CPU that cannot run the reference platform."""
    from ..numeric import pinned_environment

    pinned = pinned_environment()
    if not pinned:
        return []
    lines = ["# the numeric platform (x86-64-v3: the same bytes on every such CPU), unless set already"]
    for variable, value in pinned.items():
        lines.append(f'export {variable}="${{{variable}:-{value}}}"')
    return lines


def run(args) -> int:
    from ..usd.plugin import defaults, environment, list_separator

    if args.json:
        from .. import jsontext

        env = environment()
        from ..numeric import pinned_environment

        print(jsontext.dumps({"variables": env, "separators": {v: list_separator(v) for v in env},
                              "defaults": defaults(), "numeric": pinned_environment()}))
    else:
        print("\n".join(shell_lines()))
    return 0
