#!/usr/bin/env bash
# One-shot set-up for sigma on a fresh machine or a laptop:
#   1. find Python 3.12 (PATH first, then pyenv's installed versions),
#   2. install the Debian packages for headless MuJoCo rendering when missing and we may (root, apt),
#   3. create .venv and install sigma editable with its dev and cluster (DataTrove) extras,
#   4. pick MUJOCO_GL (egl, else osmesa) by actually opening a context, and record the choice in the venv.
set -euo pipefail

cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
say() { printf '[sigma setup] %s\n' "$*"; }

find_python() {
  local cand v
  for cand in "${PYTHON:-}" python3.12 python3 python; do
    [[ -n "$cand" ]] || continue
    command -v "$cand" >/dev/null 2>&1 || continue
    v=$("$cand" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null) || continue
    [[ "$v" == "3.12" ]] && { command -v "$cand"; return 0; }
  done
  local root=${PYENV_ROOT:-$HOME/.pyenv}
  for cand in $(ls -d "$root"/versions/3.12.*/bin/python3.12 2>/dev/null | sort -V -r); do
    "$cand" -c 'import venv' 2>/dev/null && { echo "$cand"; return 0; }
  done
  return 1
}

if [[ ! -x "$VENV/bin/python" ]]; then
  PY=$(find_python) || {
    echo "sigma needs Python 3.12 (LeRobot 0.6 requires it) and none was found on PATH or under pyenv." >&2
    echo "Install one, e.g. 'pyenv install 3.12' or your OS package 'python3.12 python3.12-venv'," >&2
    echo "or point PYTHON=/path/to/python3.12 at it, then run 'make setup' again." >&2
    exit 1
  }
  say "using $PY ($("$PY" --version 2>&1))"
  "$PY" -m venv "$VENV"
fi

# Headless OpenGL for MuJoCo: EGL (Mesa llvmpipe) plus OSMesa as the fallback.
need=()
if command -v dpkg-query >/dev/null 2>&1; then
  for p in libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || need+=("$p")
  done
  if ((${#need[@]})); then
    if [[ $(id -u) == 0 ]] && command -v apt-get >/dev/null 2>&1; then
      say "installing Debian packages for headless rendering: ${need[*]}"
      export DEBIAN_FRONTEND=noninteractive
      apt-get update -qq >/dev/null && apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
    else
      say "missing ${need[*]} (headless MuJoCo rendering); install them with: sudo apt-get install ${need[*]}"
    fi
  fi
fi

say "installing sigma and its stack into $VENV (first run downloads torch, LeRobot, robosuite: a few minutes)"
"$VENV/bin/python" -m pip install -q --disable-pip-version-check --upgrade pip >/dev/null
"$VENV/bin/python" -m pip install -q --disable-pip-version-check -e ".[dev,cluster]" 2>&1 \
  | grep -v -E "^WARNING: Location 'file:" || true
"$VENV/bin/python" -m pip check >/dev/null || { "$VENV/bin/python" -m pip check; exit 1; }

# Pick the MuJoCo GL backend by opening a real offscreen context, and record it for every later process.
gl=""
for backend in egl osmesa; do
  if MUJOCO_GL=$backend PYOPENGL_PLATFORM=$backend "$VENV/bin/python" - <<'PY' >/dev/null 2>&1
import mujoco
ctx = mujoco.GLContext(16, 16)
ctx.make_current()
ctx.free()
PY
  then gl=$backend; break; fi
done
if [[ -z "$gl" ]]; then
  echo "[sigma setup] no headless OpenGL backend works (tried egl, osmesa); install libegl1 libegl-mesa0 libgl1-mesa-dri or libosmesa6" >&2
  exit 1
fi
echo "$gl" > "$VENV/sigma_mujoco_gl"
say "MUJOCO_GL=$gl (recorded in $VENV/sigma_mujoco_gl; set MUJOCO_GL yourself to override)"
say "ready: $("$VENV/bin/python" --version), $("$VENV/bin/python" -c 'import lerobot, robosuite, mujoco, torch; print(f"lerobot {lerobot.__version__}, robosuite {robosuite.__version__}, mujoco {mujoco.__version__}, torch {torch.__version__}")' 2>/dev/null)"
