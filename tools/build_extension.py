"""Build the Blender extension zip: download the wheels the manifest lists, then build and validate
with Blender's own extension tool (``blender_ext.py`` inside the installed bpy package).

    .venv/bin/python tools/build_extension.py                    # all platforms, one zip in dist/
    .venv/bin/python tools/build_extension.py --split-platforms  # one zip per platform

``blender_manifest.toml`` is the one list of wheels: each file name gives the package, version and
platform tag that ``pip download`` fetches into ``wheels/`` (not committed).
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = ROOT / "blender_manifest.toml"


def find_blender_ext() -> Path:
    """blender_ext.py of the bpy package installed for this Python (bpy/<version>/scripts/addons_core/...)."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or spec.origin is None:
        raise SystemExit("bpy is not installed for this Python; run with the project's .venv/bin/python "
                         "or pass --blender-ext")
    found = sorted(Path(spec.origin).parent.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        raise SystemExit(f"no blender_ext.py inside {Path(spec.origin).parent}")
    return found[-1]


def download_wheel(path: Path) -> None:
    """pip download exactly the wheel named ``path`` into its folder."""
    if path.exists():
        return
    name, version, python, abi, platform_tags = path.name[:-len(".whl")].split("-")
    command = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "--dest", str(path.parent)]
    if platform_tags != "any":  # a pure Python wheel (py3-none-any) fits every target as it is
        command += ["--python-version", python[2:3] + "." + python[3:], "--implementation", python[:2], "--abi", abi]
        for tag in platform_tags.split("."):
            command += ["--platform", tag]
    command.append(f"{name}=={version}")
    print("$", " ".join(command))
    subprocess.run(command, check=True)
    if not path.exists():
        raise SystemExit(f"pip did not produce {path.name}; update the wheel names in {MANIFEST.name}")


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output-dir", type=Path, default=ROOT / "dist")
    parser.add_argument("--split-platforms", action="store_true", help="one zip per platform")
    parser.add_argument("--blender-ext", type=Path, help="path of Blender's blender_ext.py")
    args = parser.parse_args(argv)

    manifest = tomllib.loads(MANIFEST.read_text())
    wheels = [ROOT / entry for entry in manifest.get("wheels", [])]
    (ROOT / "wheels").mkdir(exist_ok=True)
    for wheel in wheels:
        download_wheel(wheel)

    tool = args.blender_ext or find_blender_ext()
    args.output_dir.mkdir(parents=True, exist_ok=True)
    build = [sys.executable, str(tool), "build", "--source-dir", str(ROOT), "--output-dir", str(args.output_dir)]
    if args.split_platforms:
        build.append("--split-platforms")
    print("$", " ".join(build))
    subprocess.run(build, check=True)

    packages = sorted(args.output_dir.glob(f"{manifest['id']}-{manifest['version']}*.zip"))
    for package in packages:
        subprocess.run([sys.executable, str(tool), "validate", str(package)], check=True)
        print(f"built and validated {package.relative_to(ROOT) if package.is_relative_to(ROOT) else package}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
