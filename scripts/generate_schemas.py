"""Regenerate zenslam/schemas/zenslam_pb2.py(.pyi) from zenslam.proto with grpcio-tools' bundled protoc.

Usage: ``python scripts/generate_schemas.py`` rewrites the generated files in place;
``python scripts/generate_schemas.py --check`` exits 1 when they are stale. The generated code
stamps protoc's protobuf version into a runtime check, so pin the protobuf runtime to that
major.minor or newer (pyproject.toml).
"""

from __future__ import annotations

import argparse
import filecmp
import sys
import tempfile
from importlib import resources
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
PROTO = Path("zenslam/schemas/zenslam.proto")  # relative to REPO_ROOT: also the descriptor's name
GENERATED = (Path("zenslam/schemas/zenslam_pb2.py"), Path("zenslam/schemas/zenslam_pb2.pyi"))


def generate(out_dir: Path) -> list[Path]:
    """Run protoc on the schema, writing the generated files under ``out_dir`` (package layout)."""
    try:
        from grpc_tools import protoc
    except ModuleNotFoundError as exc:
        raise SystemExit("grpcio-tools is not installed: pip install -e '.[dev]' (it provides protoc)") from exc
    well_known = resources.files("grpc_tools") / "_proto"
    args = [
        "protoc",
        f"-I{REPO_ROOT}",
        f"-I{well_known}",
        f"--python_out={out_dir}",
        f"--pyi_out={out_dir}",
        str(REPO_ROOT / PROTO),
    ]
    status = protoc.main(args)
    if status != 0:
        raise SystemExit(f"protoc failed on {PROTO} with status {status}")
    return [out_dir / g for g in GENERATED]


def stale_files() -> list[Path]:
    """The generated files that differ from a fresh generation (empty when up to date)."""
    with tempfile.TemporaryDirectory() as tmp:
        fresh = generate(Path(tmp))
        return [g for g, f in zip(GENERATED, fresh) if not (REPO_ROOT / g).is_file() or not filecmp.cmp(REPO_ROOT / g, f, shallow=False)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only report whether the generated files are stale")
    args = parser.parse_args(argv)
    if args.check:
        stale = stale_files()
        for path in stale:
            print(f"stale: {path} (run python scripts/generate_schemas.py)")
        return 1 if stale else 0
    generate(REPO_ROOT)
    for path in GENERATED:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
