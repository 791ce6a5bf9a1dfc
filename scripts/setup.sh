#!/usr/bin/env bash
# Sets up printer-codegen on a fresh Debian machine: the toolchains and simulators from Debian (only those
# missing), then a virtual environment in .venv with the package (a plain, non-editable install) and pytest.
# With --tests also chromium, in which the tests render the report pages (headless).
set -euo pipefail
cd "$(dirname "$0")/.."

packages=(gcc gcc-avr avr-libc binutils-avr simavr libsimavr-dev libelf-dev sdcc sdcc-ucsim python3-venv)
[ "${1:-}" = "--tests" ] && packages+=(chromium)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  echo "setup: installing ${missing[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${missing[@]}" >/dev/null
fi

[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/python -m pip install -q --disable-pip-version-check ".[test]"
echo "setup: ready ($(.venv/bin/printer-codegen --version))"
