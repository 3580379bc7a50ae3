#!/usr/bin/env bash
# Installs what the project needs: an LLVM >= 16 runtime for Dr.Jit's CPU backend, a C++ compiler for the
# BVH build's extension (native/; cmake and ninja come from PyPI, pinned in native/pyproject.toml),
# headless Chromium and its driver for the report viewer's browser test, then a virtual environment
# with the package, Mitsuba and the test tools.
#   bash scripts/setup.sh [VENV] [--peers]    (--peers, or PEERS=1: also VENV-peers with the built-in peers,
#                                              Blender's Cycles and LuxCoreRender: about 1.4 GB, 1 minute)
set -euo pipefail
VENV="${1:-.venv}"
[ "${2:-}" = "--peers" ] && PEERS=1

have_llvm() {
    ldconfig -p 2>/dev/null | grep -Eq 'libLLVM(-|\.so\.)(1[6-9]|[2-9][0-9])'
}

if ! have_llvm; then
    if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
        echo "setup: installing libllvm19 (Dr.Jit's CPU backend needs LLVM >= 16)"
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null
    else
        echo "setup: Dr.Jit's CPU backend needs an LLVM runtime >= 16 (Debian/Ubuntu: apt-get install libllvm19;" \
             "elsewhere install LLVM 16+ and set DRJIT_LIBLLVM_PATH to its libLLVM.so)" >&2
        exit 1
    fi
fi

have_python_headers() {
    python3 -c 'import os, sys, sysconfig; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))'
}

if ! command -v g++ >/dev/null || ! have_python_headers; then
    if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
        echo "setup: installing g++ and python3-dev (the BVH build's compiled extension, native/)"
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq g++ python3-dev >/dev/null
    else
        echo "setup: the BVH build's extension (native/) needs a C++17 compiler and Python's headers" \
             "(Debian/Ubuntu: apt-get install g++ python3-dev)" >&2
        exit 1
    fi
fi

if ! { command -v chromium >/dev/null || command -v chromium-browser >/dev/null; } || ! command -v chromedriver >/dev/null; then
    if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
        echo "setup: installing chromium and chromium-driver (the report viewer's browser test)"
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null
    else
        echo "setup: no chromium/chromedriver: tests/test_viewer_browser.py will skip outside CI" \
             "(Debian/Ubuntu: apt-get install chromium chromium-driver)" >&2
    fi
fi

python3 -m venv "$VENV"
"$VENV/bin/pip" install -q --upgrade pip
"$VENV/bin/pip" install -q ./native     # the BVH build's compiled phases (C++; about 1 to 2 minutes)
"$VENV/bin/pip" install -q -e ".[test]"
if [ "${PEERS:-0}" = 1 ]; then
    # the peers' own environment (bpy needs NumPy 1.x): the pins of pyproject.toml's `peers` extra
    echo "setup: installing the peers (Cycles, LuxCoreRender) into $VENV-peers"
    python3 -m venv "$VENV-peers"
    "$VENV-peers/bin/pip" install -q --upgrade pip
    "$VENV/bin/python" -c "import tomllib; print('\n'.join(tomllib.load(open('pyproject.toml', 'rb'))['project']['optional-dependencies']['peers']))" \
        | xargs "$VENV-peers/bin/pip" install -q
fi
echo "setup: done ($VENV)"
