# Shared by run.sh and test.sh: install missing Debian packages, configure, build.
# Sourced, not executed.

PHYS_PACKAGES=(cmake ninja-build g++ pkg-config libeigen3-dev nlohmann-json3-dev libqhull-dev
  libgtest-dev libgmock-dev libcli11-dev
  cyclonedds-dev cyclonedds-tools libflatbuffers-dev flatbuffers-compiler libspdlog-dev
  libtomlplusplus-dev zlib1g-dev libssl-dev bc python3
  libvulkan-dev glslc mesa-vulkan-drivers vulkan-validationlayers vulkan-tools
  libbullet-dev libode-dev libmujoco-dev gnuplot-nox
  python3-dev pybind11-dev
  libcivetweb-dev nodejs chromium
  libcurl4-openssl-dev etcd-server)

phys_install_deps() {
  local missing=()
  for p in "${PHYS_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  # npm (the viewer's page is bundled at build time): Debian's package, unless a nodejs that
  # brings its own npm is installed (NodeSource's conflicts with Debian's npm).
  command -v npm >/dev/null || missing+=(npm)
  [ ${#missing[@]} -eq 0 ] && return 0
  echo "Installing missing packages: ${missing[*]}"
  local sudo=""
  [ "$(id -u)" -ne 0 ] && sudo="sudo"
  # Another apt-get may hold the dpkg lock (e.g. unattended upgrades): wait for it.
  local tries=0
  while command -v fuser >/dev/null && fuser /var/lib/dpkg/lock-frontend >/dev/null 2>&1; do
    tries=$((tries + 1)); [ $tries -gt 120 ] && { echo "dpkg lock held for 4 minutes" >&2; return 1; }
    sleep 2
  done
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
}

# phys_build DIR [extra cmake args...]: configure once, then build incrementally.
# Optimised, with line tables only (-g1: functions, files and lines for backtraces, perf and
# sanitizer reports; no variables or types): the build from a fresh clone takes a third less
# compile time than with -g (tests/server/test_core.cpp: 13.2 -> 8.9 s). For a debugger's
# view of variables, configure a build folder of your own with -DCMAKE_BUILD_TYPE=Debug.
phys_build() {
  local dir=$1; shift
  if [ ! -f "$dir/build.ninja" ]; then
    cmake -S . -B "$dir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
      "-DCMAKE_CXX_FLAGS_RELWITHDEBINFO=-O2 -g1 -DNDEBUG" \
      "-DCMAKE_C_FLAGS_RELWITHDEBINFO=-O2 -g1 -DNDEBUG" "$@"
  fi
  cmake --build "$dir" --parallel "$(nproc)"
}
