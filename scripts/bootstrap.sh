#!/usr/bin/env bash
# Shared set-up for ./run and ./test: system packages (when root), a .venv, the package.
# Idempotent and quick when nothing changed. Source it; it defines $GV_PY and $GV_BIN.
set -euo pipefail
GV_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"

# Mesa EGL (headless GL), Qt's xcb libraries and Xvfb (a real X display for the window tests),
# nginx and its echo module (the real static web server the remote-store tests serve stores
# with, as a user of the store; echo_sleep adds a far server's latency). The tests start nginx
# themselves on a free port with their own configuration; the package's own service (port 80)
# is not used: `systemctl disable --now nginx` on a machine that started it.
GV_APT_PACKAGES=(
  libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 libopengl0
  xvfb xauth
  nginx libnginx-mod-http-echo
  libxcb-icccm4 libxcb-image0 libxcb-keysyms1 libxcb-render-util0 libxcb-xinerama0
  libxcb-xkb1 libxkbcommon-x11-0 libxkbcommon0 libxcb-shape0 libxcb-randr0 libxcb-cursor0
  libfontconfig1 libdbus-1-3 libglib2.0-0
)

gv_missing_apt() {
  local missing=()
  for p in "${GV_APT_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  echo "${missing[@]:-}"
}

if command -v dpkg-query >/dev/null 2>&1; then
  missing="$(gv_missing_apt)"
  if [ -n "$missing" ]; then
    if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
      echo "bootstrap: installing system packages: $missing" >&2
      export DEBIAN_FRONTEND=noninteractive
      apt-get install -y -qq $missing >/dev/null 2>&1 || {
        apt-get update -qq >/dev/null
        apt-get install -y -qq $missing >/dev/null
      }
    else
      echo "bootstrap: missing system packages (install them as root): $missing" >&2
    fi
  fi
fi

PYTHON="${PYTHON:-python3}"
GV_VENV="$GV_ROOT/.venv"
GV_PY="$GV_VENV/bin/python"
GV_BIN="$GV_VENV/bin"
# Reinstall when what pip installs changed: pyproject.toml less the tools' own settings (a
# ruff, mypy, pytest or import-linter setting needs no reinstall, so ./test --fast stays quick).
stamp_src="$(awk '/^\[/ { skip = ($0 ~ /^\[\[?tool\.(ruff|mypy|pytest|importlinter)/) } !skip' \
  "$GV_ROOT/pyproject.toml" | sha256sum | cut -d' ' -f1)"
if [ ! -x "$GV_PY" ]; then
  echo "bootstrap: creating $GV_VENV" >&2
  "$PYTHON" -m venv "$GV_VENV"
fi
if [ ! -f "$GV_VENV/.gv-stamp" ] || [ "$(cat "$GV_VENV/.gv-stamp")" != "$stamp_src" ]; then
  echo "bootstrap: installing globeview and its dependencies into .venv" >&2
  log="$GV_VENV/pip-install.log"
  gv_pip() {
    "$GV_PY" -m pip install -q --disable-pip-version-check "$@" >>"$log" 2>&1 || {
      cat "$log" >&2
      echo "bootstrap: pip install failed (log above)" >&2
      exit 1
    }
  }
  : >"$log"
  gv_pip -e "$GV_ROOT[test,bench]"
  # The example plugin is its own pip package; installing it makes its entry point real.
  if [ -f "$GV_ROOT/examples/globeview-fixedlevel/pyproject.toml" ]; then
    gv_pip -e "$GV_ROOT/examples/globeview-fixedlevel"
  fi
  echo "$stamp_src" > "$GV_VENV/.gv-stamp"
fi
export GV_PY GV_BIN GV_ROOT
