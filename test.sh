#!/usr/bin/env bash
# Installs what is missing, builds, and runs every test through ctest.
set -euo pipefail
cd "$(dirname "$0")"
source scripts/common.sh
phys_install_deps
phys_build build
cd build
ctest --output-on-failure --parallel "$(nproc)" "$@"
