#!/usr/bin/env bash
# Idempotent set-up: the Debian packages the toolkit needs (when missing), then the Python side
# in .venv inside the checkout. Run by `make demo`, and as `setup.sh test` by `make test`, which
# also needs a browser for the report viewer's tests; safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."

# libllvm19: Mitsuba's llvm_ad_rgb variant (LLVM 15/16 abort the process, 14 is refused).
# libegl1, libgl1, libgl1-mesa-dri: headless OpenGL 4.5 through EGL, llvmpipe when there is no GPU.
debs=(libllvm19 libegl1 libgl1 libgl1-mesa-dri)
# chromium, chromium-driver: headless Chromium driven by Selenium (tests/test_viewer.py).
if [ "${1:-}" = "test" ]; then
    debs+=(chromium chromium-driver)
fi
missing=()
for p in "${debs[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    echo "setup: installing Debian packages: ${missing[*]}"
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

python=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$python" -m venv .venv
# Reinstall only when the project's declared dependencies changed since the last install.
stamp=.venv/.installed-$(sha256sum pyproject.toml | cut -c1-16)
if [ ! -f "$stamp" ]; then
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e ".[test,docs]"
    rm -f .venv/.installed-*
    touch "$stamp"
fi
