"""``vswrist export``: the wrist as a self-contained MJCF file for other MuJoCo programs.

The file names its springs and motors as MuJoCo plugins (``vswrist.drive``, ``vswrist.closure``), so it
loads wherever the plugin library is loaded: the command prints the library's path. In Python:
``mujoco.mj_loadPluginLibrary(PATH)`` before loading the file (with vswrist-gym installed, ``import mujoco``
does it itself, so ``python -m mujoco.viewer --mjcf FILE`` works as is); in C/C++ ``mj_loadPluginLibrary``;
MuJoCo's ``simulate`` loads every library in the ``plugin`` directory beside its executable.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import mujoco

from ..params import PRESETS, ParamsError, load_params
from . import native
from .builder import export_xml


def export(params, out: str | Path) -> tuple[Path, Path]:
    """Write the wrist of ``params`` (preset name, YAML path or WristParams) to ``out``; checks that the
    written file loads. Returns (the file, the plugin library to load before it)."""
    p = load_params(params)
    library = native.load_plugin()
    xml = export_xml(p)
    out = Path(out)
    out.write_text(xml)
    mujoco.MjModel.from_xml_path(str(out))  # what a user will do next: it must load
    return out, library


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="vswrist export", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--params", default=None, help=f"preset ({', '.join(PRESETS)}) or YAML file; default paper")
    parser.add_argument("--out", required=True, help="MJCF file to write, e.g. wrist.xml")
    args = parser.parse_args(argv)
    try:
        out, library = export(args.params, args.out)
    except ParamsError as exc:
        print(f"vswrist export: --params: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # no C compiler: the fallback callbacks cannot travel with a file
        print(f"vswrist export: the compiled plugin is needed and unavailable: {str(exc).splitlines()[0]}",
              file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"vswrist export: --out: cannot write {args.out}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    print(f"wrote {out}")
    print(f"plugin library: {library}")
    print("load the library before the model, e.g. in Python:")
    print(f"  mujoco.mj_loadPluginLibrary({str(library)!r}); mujoco.MjModel.from_xml_path({str(out)!r})")
    print(f"viewer (vswrist-gym installed): python -m mujoco.viewer --mjcf {out}")
    return 0
