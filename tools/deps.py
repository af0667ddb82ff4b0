"""The tested dependencies (requirements.lock) and the checks that keep it honest (docs/dependencies.md).

    python3 tools/deps.py lock      # refresh the lock: the newest versions pyproject.toml's bounds allow
    python3 tools/deps.py drift     # those newest versions in a throwaway venv, the suite run there
    python3 tools/deps.py oldest    # the lower bounds in a throwaway venv, the suite run there
    python3 tools/deps.py audit     # the locked set against PyPI's advisory database (pip-audit)
    python3 tools/deps.py audit --advisories DIR   # offline: a clone of github.com/pypa/advisory-database

Needs only a Python 3.11 with venv: the tools (uv resolves, pip-audit audits) are installed at pinned versions
into a venv of their own under ~/.cache/pure-hil/. `drift` and `oldest` print which packages differ from the
lock and which tests failed, and exit 1 if any did.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOCK = ROOT / "requirements.lock"
EXTRAS = ("dev",)
"""The extras README's commands and .ci/run install: the lock covers exactly these."""
PYTHON = "3.11"
"""The Python the lock is resolved for (pyproject.toml's requires-python lower bound, README's Debian)."""
TOOLS = ("uv==0.13.9", "pip-audit==2.10.1", "pyyaml==6.0.3")
TOOLS_VENV = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "pure-hil" / "tools-venv"
UNLOCKED = "PURE_HIL_UNLOCKED"
"""Set in drift and oldest runs: tests/test_lock.py skips there, saying why (the set is not the lock's)."""


def tool(name: str) -> str:
    """The pinned tool's path, installed into TOOLS_VENV the first time."""
    exe = TOOLS_VENV / "bin" / name
    marker = TOOLS_VENV / "tools.txt"
    if not exe.exists() or not marker.exists() or marker.read_text() != "\n".join(TOOLS):
        shutil.rmtree(TOOLS_VENV, ignore_errors=True)
        venv.create(TOOLS_VENV, with_pip=True)
        subprocess.run([TOOLS_VENV / "bin" / "pip", "install", "--quiet", *TOOLS], check=True)
        marker.write_text("\n".join(TOOLS))
    return str(exe)


def compile_set(out: Path, *, lowest: bool = False) -> None:
    """Resolve pyproject.toml's dependencies and EXTRAS into a requirements file: the newest versions the
    bounds allow, or with lowest=True each direct dependency at its lower bound."""
    args = [tool("uv"), "pip", "compile", "pyproject.toml", "--quiet", "--upgrade", "--universal"]
    args += [
        "--python-version",
        PYTHON,
        "--custom-compile-command",
        "python3 tools/deps.py lock",
        "-o",
        str(out),
    ]
    args += [a for extra in EXTRAS for a in ("--extra", extra)]
    if lowest:
        args += ["--resolution", "lowest-direct"]
    subprocess.run(args, cwd=ROOT, check=True)


def pins(path: Path) -> dict[str, str]:
    """name -> version of a requirements file's `name==version` lines; a line with a marker is keyed by
    `name ; marker` (the lock may pin two versions of a package, one per Python)."""
    found = {}
    for line in path.read_text().splitlines():
        m = re.match(r"([A-Za-z0-9._-]+)==([^\s;]+)\s*(;.*)?$", line)
        if m:
            found[re.sub(r"[-_.]+", "-", m[1]).lower() + (f" {m[3]}" if m[3] else "")] = m[2]
    return found


def moved(new: Path) -> list[str]:
    """One line per package whose version differs between the lock and `new`."""
    old, now = pins(LOCK), pins(new)
    names = sorted(old.keys() | now.keys())
    return [f"  {n}: {old.get(n, '-')} -> {now.get(n, '-')}" for n in names if old.get(n) != now.get(n)]


def suite_in_venv(requirements: Path, label: str, pytest_args: list[str]) -> int:
    """Install `requirements` and the rig into a throwaway venv, run the suite there; print what failed."""
    where = Path(tempfile.mkdtemp(prefix=f"pure-hil-{label}-"))
    try:
        # A copy of the checkout (its files as git sees them, uncommitted changes included): the suite must
        # not import what someone edits in the checkout while it runs.
        listed = (
            subprocess.run(
                ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                cwd=ROOT,
                capture_output=True,
                check=True,
            )
            .stdout.decode()
            .split("\0")
        )
        src = where / "src"
        for name in filter(None, listed):
            if (ROOT / name).is_file():
                (src / name).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(ROOT / name, src / name)
        venv.create(where / "venv", with_pip=True)
        pip = str(where / "venv" / "bin" / "pip")
        subprocess.run([pip, "install", "--quiet", "--upgrade", "pip"], check=True)
        extras = ",".join(EXTRAS)
        install = [pip, "install", "--quiet", "-r", str(requirements), "-e", f".[{extras}]"]
        done = subprocess.run(install, cwd=src, capture_output=True, text=True)  # setuptools is verbose
        if done.returncode:
            print(f"{label}: the install failed:\n{done.stderr}")
            return done.returncode
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", **{UNLOCKED: label})
        python = str(where / "venv" / "bin" / "python")
        run = subprocess.run(
            [python, "-m", "pytest", "-n", "2", "-p", "no:cacheprovider", "-q", *pytest_args],
            cwd=src,
            env=env,
            capture_output=True,
            text=True,
        )
        failed = [line for line in run.stdout.splitlines() if line.startswith(("FAILED", "ERROR"))]
        tail = run.stdout.strip().splitlines()[-1:] if run.stdout.strip() else [run.stderr.strip()]
        kept = ROOT / "runs" / f"deps-{label}.log"
        kept.parent.mkdir(exist_ok=True)
        kept.write_text(run.stdout + run.stderr)
        print(f"{label}: the suite: {tail[0] if tail else '(no output)'} (its whole output: {kept})")
        for line in failed:
            print(f"  {line}")
        return run.returncode
    finally:
        shutil.rmtree(where, ignore_errors=True)


OFFLINE_AUDIT = """
import sys, pathlib, yaml
from packaging.version import Version
lock, root = sys.argv[1], pathlib.Path(sys.argv[2]) / "vulns"
pins = sorted(tuple(line.split("==")) for line in sys.stdin.read().split())
found = 0
for name, version in pins:
    v = Version(version)
    for path in sorted((root / name).glob("*.yaml")) if (root / name).is_dir() else []:
        record = yaml.safe_load(path.read_text())
        if record.get("withdrawn"):
            continue
        for affected in record.get("affected", []):
            hit = version in [str(x) for x in affected.get("versions", [])]
            for r in affected.get("ranges", []):
                if r.get("type") != "ECOSYSTEM":
                    continue
                start, end = None, None
                for event in r.get("events", []):
                    start = Version(event["introduced"]) if "introduced" in event else start
                    end = Version(event["fixed"]) if "fixed" in event else end
                    if start is not None and end is not None:
                        hit = hit or start <= v < end
                        start, end = None, None
                if start is not None and end is None:
                    hit = hit or start <= v
            if hit:
                found += 1
                print(f"{name} {version}: {record['id']} {', '.join(record.get('aliases', []))}")
print(f"{len(pins)} locked packages, {found} known vulnerabilities ({lock} against {root.parent})")
sys.exit(1 if found else 0)
"""
"""pip-audit's check, offline: a locked version is affected when an advisory not withdrawn lists it or an
ECOSYSTEM range (introduced .. fixed) holds it. For a bench whose network reaches no advisory service."""


def offline_audit(advisories: Path) -> int:
    python = str(Path(tool("pip-audit")).parent / "python")
    pinned = "\n".join(f"{n.split()[0]}=={v}" for n, v in pins(LOCK).items())
    args = [python, "-c", OFFLINE_AUDIT, str(LOCK.name), str(advisories)]
    run = subprocess.run(args, input=pinned, text=True)
    return run.returncode


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("action", choices=("lock", "drift", "oldest", "audit"))
    parser.add_argument(
        "pytest_args", nargs="*", help="passed to pytest (drift, oldest), e.g. -x or a test path"
    )
    parser.add_argument("--advisories", type=Path, help="audit offline: the PyPA advisory database, cloned")
    args = parser.parse_args(argv)
    if args.action == "lock":
        compile_set(LOCK)
        print(f"{LOCK.relative_to(ROOT)}: {len(pins(LOCK))} packages")
        return 0
    if args.action == "audit" and args.advisories:
        return offline_audit(args.advisories)
    if args.action == "audit":
        # --no-deps: the lock is the whole set, pinned; --disable-pip: audit the file, install nothing.
        run = subprocess.run(
            [tool("pip-audit"), "-r", str(LOCK), "--no-deps", "--disable-pip", "--progress-spinner", "off"]
        )
        return run.returncode
    with tempfile.TemporaryDirectory() as tmp:
        resolved = Path(tmp) / f"{args.action}.txt"
        compile_set(resolved, lowest=args.action == "oldest")
        changes = moved(resolved)
        print(f"{args.action}: {len(changes)} of {len(pins(resolved))} packages differ from the lock")
        print("\n".join(changes))
        return suite_in_venv(resolved, args.action, args.pytest_args)


if __name__ == "__main__":
    sys.exit(main())
