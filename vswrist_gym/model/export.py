"""``vswrist export``: the wrist as a self-contained MJCF file for other MuJoCo programs.

The file names its springs and motors as MuJoCo plugins (``vswrist.drive``, ``vswrist.closure``), so it
loads wherever the plugin library is loaded: the command prints the library's path. In Python:
``mujoco.mj_loadPluginLibrary(PATH)`` before loading the file (with vswrist-gym installed, ``import mujoco``
does it itself, so ``python -m mujoco.viewer --mjcf FILE`` works as is); in C/C++ ``mj_loadPluginLibrary``;
MuJoCo's ``simulate`` loads every library in the ``plugin`` directory beside its executable. ``--bundle DIR``
writes the file, a copy of the library and a README side by side, for a MuJoCo without vswrist-gym. The file
begins with a comment naming the library it needs. An existing file or bundle is overwritten only with --force.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import mujoco

from ..params import PRESETS, ParamsError, load_params
from . import native
from .builder import export_xml
from .plugin_lib import CLOSURE_PLUGIN, DRIVE_PLUGIN


BUNDLE_XML = "wrist.xml"
BUNDLE_LIBRARY = "libvswrist_plugin" + (".dylib" if sys.platform == "darwin" else ".so")
BUNDLE_README = "README.md"


class ExportError(ValueError):
    """An output that exists (without --force) or cannot be written."""


def header_comment(library_name: str, params_name: str) -> str:
    """The comment the exported file begins with: what it needs and how to load it, for a reader who has the
    file alone (MuJoCo's own error, 'plugin vswrist.drive not found', does not say)."""
    return (f"<!-- VS-Wrist ({params_name} parameters), exported by vswrist-gym for MuJoCo {mujoco.__version__}.\n"
            f"     Needs the MuJoCo plugin library {library_name} (plugins {DRIVE_PLUGIN}, {CLOSURE_PLUGIN}),\n"
            f"     loaded before this file: Python mujoco.mj_loadPluginLibrary(path), C mj_loadPluginLibrary(path),\n"
            f"     simulate: copy it into the plugin/ folder beside the simulate executable.\n"
            f"     `vswrist export --bundle DIR` writes the file, the library and a README side by side. -->\n")


def _check_target(path: Path, force: bool, what: str) -> None:
    if path.exists() and not force:
        raise ExportError(f"{what} {path} exists; add --force to overwrite it")
    base = path.parent if what == "--out" else (path if path.exists() else path.parent)
    if not base.is_dir():
        raise ExportError(f"{what} {path}: {base} is not an existing folder")
    if not os.access(base, os.W_OK):
        raise ExportError(f"{what} {path}: {base} is not writable")


def export(params, out: str | Path, force: bool = True) -> tuple[Path, Path]:
    """Write the wrist of ``params`` (preset name, YAML path or WristParams) to ``out``, beginning with a comment
    that names the plugin library; checks that the written file loads. Returns (the file, the plugin library
    to load before it). ``force=False`` refuses an existing file."""
    p = load_params(params)
    out = Path(out)
    if not force and out.exists():
        raise ExportError(f"--out {out} exists; add --force to overwrite it")
    library = native.load_plugin()
    xml = header_comment(library.name, p.name) + export_xml(p)
    out.write_text(xml)
    mujoco.MjModel.from_xml_path(str(out))  # what a user will do next: it must load
    return out, library


def bundle_readme(params_name: str) -> str:
    lib, xml = BUNDLE_LIBRARY, BUNDLE_XML
    return f"""# VS-Wrist for MuJoCo ({params_name} parameters)

`{xml}` is the wrist as an MJCF model; its springs and motors are MuJoCo engine plugins
(`{DRIVE_PLUGIN}`, `{CLOSURE_PLUGIN}`) compiled into `{lib}`, built for MuJoCo {mujoco.__version__} on
{sys.platform}. Load the library before the model; without it MuJoCo stops with
`plugin {DRIVE_PLUGIN} not found`. Nothing else of vswrist-gym is needed.

Python (`pip install mujoco=={mujoco.__version__}`):

```python
import mujoco
mujoco.mj_loadPluginLibrary("./{lib}")  # a path: a bare name is searched in the system's folders
model = mujoco.MjModel.from_xml_path("{xml}")
data = mujoco.MjData(model)
mujoco.mj_resetDataKeyframe(model, data, model.key("home_stiff").id)  # or "home": no preload
mujoco.mj_step(model, data, 100)
```

C:

```c
mj_loadPluginLibrary("./{lib}");
char error[1000];
mjModel* m = mj_loadXML("{xml}", NULL, error, sizeof(error));
```

`simulate`: copy `{lib}` into the `plugin/` folder beside the `simulate` executable (it loads every library
there at start), then open `{xml}` (drag it into the window, or `simulate {xml}`).

Actuators `motor_A`, `motor_B`, `motor_C`, `motor_ps`: motor angle references (rad); `home_stiff` is the
stiffest preload the motor limits allow at the home posture.
"""


def export_bundle(params, folder: str | Path, force: bool = False) -> Path:
    """Write FOLDER/{wrist.xml, the plugin library, README.md}: the wrist for a MuJoCo without vswrist-gym. The
    files are written under temporary names and renamed, and the folder is checked to load."""
    folder = Path(folder)
    p = load_params(params)
    if folder.exists() and not folder.is_dir():
        raise ExportError(f"--bundle {folder} is a file")
    names = (BUNDLE_XML, BUNDLE_LIBRARY, BUNDLE_README)
    if folder.is_dir():
        present = [n for n in names if (folder / n).exists()]
        if present and not force:
            raise ExportError(f"--bundle {folder} already holds {', '.join(present)}; add --force to overwrite")
        other = sorted(q.name for q in folder.iterdir() if q.name not in names)
        if other:
            raise ExportError(f"--bundle {folder} holds other files ({', '.join(other[:3])}); choose a new or empty "
                              f"folder")
    _check_target(folder, True, "--bundle")
    library = native.load_plugin()
    folder.mkdir(parents=True, exist_ok=True)
    files = {BUNDLE_XML: (header_comment(BUNDLE_LIBRARY, p.name) + export_xml(p)).encode(),
             BUNDLE_LIBRARY: library.read_bytes(), BUNDLE_README: bundle_readme(p.name).encode()}
    for name, data in files.items():
        tmp = folder / f".{name}.tmp"
        tmp.write_bytes(data)
        os.replace(tmp, folder / name)
    (folder / BUNDLE_LIBRARY).chmod(0o755)
    mujoco.MjModel.from_xml_path(str(folder / BUNDLE_XML))  # loads (with the library this process holds)
    return folder


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="vswrist export", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--params", default=None, help=f"preset ({', '.join(PRESETS)}) or YAML file; default paper")
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--out", help="MJCF file to write, e.g. wrist.xml")
    where.add_argument("--bundle", help=f"folder to write {BUNDLE_XML}, the plugin library ({BUNDLE_LIBRARY}) "
                                        f"and a README into: the wrist for a MuJoCo without vswrist-gym")
    parser.add_argument("--force", action="store_true", help="overwrite an existing file or bundle")
    args = parser.parse_args(argv)
    try:
        if args.bundle is not None:
            folder = export_bundle(args.params, args.bundle, force=args.force)
        else:
            _check_target(Path(args.out), args.force, "--out")
            out, library = export(args.params, args.out)
    except ExportError as exc:
        print(f"vswrist export: {exc}", file=sys.stderr)
        return 2
    except ParamsError as exc:
        print(f"vswrist export: --params: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # no C compiler: the reference callbacks cannot travel with a file
        print(f"vswrist export: the compiled plugin is needed and unavailable: {str(exc).splitlines()[0]}",
              file=sys.stderr)
        return 2
    except OSError as exc:
        target = args.bundle or args.out
        print(f"vswrist export: {'--bundle' if args.bundle else '--out'}: cannot write {target}: "
              f"{exc.strerror or exc}", file=sys.stderr)
        return 2
    if args.bundle is not None:
        print(f"wrote {folder / BUNDLE_XML}, {folder / BUNDLE_LIBRARY} and {folder / BUNDLE_README}")
        print(f"in Python: mujoco.mj_loadPluginLibrary({str(folder / BUNDLE_LIBRARY)!r}); "
              f"mujoco.MjModel.from_xml_path({str(folder / BUNDLE_XML)!r})")
        return 0
    print(f"wrote {out}")
    print(f"plugin library: {library}")
    print("load the library before the model, e.g. in Python:")
    print(f"  mujoco.mj_loadPluginLibrary({str(library)!r}); mujoco.MjModel.from_xml_path({str(out)!r})")
    print(f"viewer (vswrist-gym installed): python -m mujoco.viewer --mjcf {out}")
    print("for a MuJoCo without vswrist-gym: vswrist export --bundle DIR (the file, the library and a README)")
    return 0
