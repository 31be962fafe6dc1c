#!/usr/bin/env bash
# Installs what is missing, builds, and runs the default scene with a live readout.
set -euo pipefail
cd "$(dirname "$0")"
source scripts/common.sh
phys_install_deps
phys_build build
exec build/tools/physdemo "$@"
