"""``solaris-engine setup-minecraft``: install the real-Minecraft backend (idempotent).

Steps, each skipped when already done: the Debian build packages + Xvfb (apt-get, as root), ``npm ci``
from the committed ``package-lock.json`` (native builds of canvas and headless-gl from source: the
prebuilt binaries cannot be downloaded; ~4-5 min cold), the flying-squid player-list fix
(``patch-flying-squid.js``), then a check that the native modules load. Each missing prerequisite
gets its own message.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

from solaris_env.engine.minecraft import NODE_DIR

# Node packages whose presence (with native builds) means the backend is set up.
NATIVE_MODULES = ("canvas", "gl", "node-canvas-webgl", "prismarine-viewer", "mineflayer", "flying-squid")
NODE_MAJOR_MIN = 20
DEBIAN_PACKAGES = ("build-essential", "pkg-config", "python3", "libxi-dev", "libglu1-mesa-dev", "libglew-dev",
                   "libcairo2-dev", "libpango1.0-dev", "libjpeg-dev", "libgif-dev", "librsvg2-dev", "xvfb")
NATIVE_ADDONS = ("node_modules/canvas/build/Release/canvas.node",
                 "node_modules/gl/build/Release/webgl.node",
                 "node_modules/node-canvas-webgl/node_modules/canvas/build/Release/canvas.node")
PATCH_SCRIPT = "patch-flying-squid.js"
PATCH_MARKER = "serv._writeAll('player_info'"


def node_major() -> int | None:
    node = shutil.which("node")
    if node is None:
        return None
    out = subprocess.run([node, "--version"], check=False, capture_output=True, text=True).stdout.strip()
    try:
        return int(out.lstrip("v").split(".")[0])
    except ValueError:
        return None


def missing_debian_packages() -> list[str]:
    if shutil.which("dpkg-query") is None:
        return list(DEBIAN_PACKAGES)
    missing = []
    for pkg in DEBIAN_PACKAGES:
        r = subprocess.run(["dpkg-query", "-W", "-f=${Status}", pkg], check=False, capture_output=True, text=True)
        if "install ok installed" not in r.stdout:
            missing.append(pkg)
    return missing


def patch_applied() -> bool:
    login = NODE_DIR / "node_modules/flying-squid/src/lib/plugins/login.js"
    return login.is_file() and PATCH_MARKER in login.read_text()


def check_installed() -> list[str]:
    """One message per missing prerequisite (empty = the backend is ready)."""
    problems = []
    major = node_major()
    if major is None:
        problems.append("node is not on PATH (install Node >= 20, e.g. Debian's nodejs)")
    elif major < NODE_MAJOR_MIN:
        problems.append(f"node {major} is too old (need >= {NODE_MAJOR_MIN})")
    if shutil.which("Xvfb") is None:
        problems.append("Xvfb is not installed (Debian package xvfb; `solaris-engine setup-minecraft`)")
    for mod in NATIVE_MODULES:
        if not (NODE_DIR / "node_modules" / mod / "package.json").is_file():
            problems.append(f"node module {mod} is not installed (run `solaris-engine setup-minecraft`)")
    for addon in NATIVE_ADDONS:
        if (NODE_DIR / addon.split("/build/")[0]).is_dir() and not (NODE_DIR / addon).is_file():
            problems.append(f"native addon {addon} was not built (run `solaris-engine setup-minecraft`)")
    if (NODE_DIR / "node_modules/flying-squid").is_dir() and not patch_applied():
        problems.append("the flying-squid player-list fix is not applied (run `solaris-engine setup-minecraft`)")
    return problems


def setup_problem() -> str | None:
    """None when the backend is installed and runnable here, else a sentence naming what is missing."""
    missing = check_installed()
    return "; ".join(missing) if missing else None


def _run(argv: list[str], what: str, cwd=None, env=None) -> None:
    print(f"setup-minecraft: {what}: {' '.join(argv)}", file=sys.stderr, flush=True)
    r = subprocess.run(argv, check=False, cwd=cwd, env=env)
    if r.returncode != 0:
        raise SystemExit(f"setup-minecraft: {what} failed with status {r.returncode}")


def setup(skip_apt: bool = False, force_npm: bool = False) -> int:
    """Install everything that is missing; returns 0 when the backend is ready."""
    major = node_major()
    if major is None or major < NODE_MAJOR_MIN:
        raise SystemExit(f"setup-minecraft: Node >= {NODE_MAJOR_MIN} is required (found {major}); "
                         "install Debian's nodejs or Node 20 first")
    if shutil.which("npm") is None:
        raise SystemExit("setup-minecraft: npm is not on PATH (Debian package npm)")
    missing = missing_debian_packages()
    if missing and skip_apt:
        raise SystemExit(f"setup-minecraft: missing Debian packages {missing} (--skip-apt given)")
    if missing:
        if os.geteuid() != 0:
            raise SystemExit("setup-minecraft: missing Debian packages; as root run:\n  apt-get install -y "
                             + " ".join(missing))
        env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
        _run(["apt-get", "update", "-qq"], "apt-get update", env=env)
        _run(["apt-get", "install", "-y", "-qq", *missing], "Debian build packages + Xvfb", env=env)
    modules_ok = all((NODE_DIR / "node_modules" / m / "package.json").is_file() for m in NATIVE_MODULES) and all(
        (NODE_DIR / a).is_file() for a in NATIVE_ADDONS)
    if force_npm or not modules_ok:
        # nodedir: the Debian node headers, so node-gyp does not try to download them.
        env = dict(os.environ)
        if os.path.isfile("/usr/include/node/node.h"):
            env.setdefault("npm_config_nodedir", "/usr")
        _run(["npm", "ci", "--no-audit", "--no-fund"], "npm ci (native builds take minutes)", cwd=NODE_DIR, env=env)
    else:
        print("setup-minecraft: node_modules already built (use --force-npm to rebuild)", file=sys.stderr)
    _run(["node", PATCH_SCRIPT], "flying-squid player-list fix", cwd=NODE_DIR)
    problems = check_installed()
    if problems:
        raise SystemExit("setup-minecraft: still missing:\n  " + "\n  ".join(problems))
    probe = "require('node-canvas-webgl/lib'); require('mineflayer'); require('flying-squid'); console.log('ok')"
    _run(["node", "-e", probe], "load check of the native modules", cwd=NODE_DIR)
    print("setup-minecraft: ready", file=sys.stderr)
    return 0
