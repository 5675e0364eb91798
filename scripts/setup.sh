#!/usr/bin/env bash
# Idempotent set-up for a fresh machine: system packages, a virtualenv in .venv, the project with all extras.
# Both README commands (make demo, make test) call this first; a second run costs a second.
set -euo pipefail
cd "$(dirname "$0")/.."

# Everything the tests need, so none of them skips (under CI=true a skip fails): chromium for the page tests
# (Playwright drives /usr/bin/chromium; its Python package comes with the dev extra), systemd (systemd-analyze,
# -sysusers, -tmpfiles) and cage to verify the shipped units, libseccomp2 for the sandbox test, libsystemd-dev +
# pkg-config to build the journal extra. The tests that need root need CI to run as root.
apt_pkgs=(libsystemd-dev pkg-config chromium systemd cage libseccomp2)
missing=()
for p in "${apt_pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "setup: installing system packages: ${missing[*]}"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
  else
    echo "setup: missing system packages (${missing[*]}); install them as root. Continuing without them." >&2
  fi
fi

py=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$py" -m venv .venv
stamp=.venv/.vtkiosk-setup
want=$(cat pyproject.toml constraints.txt scripts/setup.sh | sha256sum | cut -c1-16)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "setup: installing Python packages into .venv (first run takes a few minutes)"
  .venv/bin/pip install -q --upgrade pip
  # torch first, from the CPU wheel; the constraints file keeps every later resolve on it.
  .venv/bin/pip install -q -c constraints.txt "torch==2.13.0"
  extras="train,export,fleet,openvino,dev"
  if pkg-config --exists libsystemd 2>/dev/null; then extras="$extras,journal"; fi
  .venv/bin/pip install -q -c constraints.txt -e ".[${extras}]"
  echo "$want" > "$stamp"
fi
