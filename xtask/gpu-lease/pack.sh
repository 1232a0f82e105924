#!/bin/bash
# Builds the wgpu binaries on this machine and packs them for a lent GPU machine that has no
# Rust toolchain (docs/gpu.md, "On a lent GPU machine"): the CLI, the GPU benchmark and the
# wgpu tests, stripped and xz-compressed into .devbin/ (about 26 MB), plus the Vulkan loader
# and GL dispatch libraries as Debian packages in .gl/. Both folders are git-ignored; name
# them in the lease's `carry`.
set -euo pipefail
cd "$(dirname "$0")/../.."
CARGO_TARGET_DIR=target/wgpu cargo test --workspace --release --features wonder3d-cli/wgpu --no-run \
    --test wgpu --test commands --bench gpu 2>&1 | tee /tmp/gpu-lease-build.log
newest() { ls -t target/wgpu/release/deps/ | grep -E "^$1-[0-9a-f]+$" | head -1; }
mkdir -p .devbin .gl
rm -f .devbin/*.txz
cp target/wgpu/release/wonder3d .devbin/wonder3d
cp "target/wgpu/release/deps/$(newest gpu)" .devbin/gpu-bench
cp "target/wgpu/release/deps/$(newest wgpu)" .devbin/wgpu-test
(cd .devbin && strip wonder3d gpu-bench wgpu-test && tar cf - wonder3d gpu-bench wgpu-test | xz -6 -T0 > bins.txz \
    && rm wonder3d gpu-bench wgpu-test)
pwd > .devbin/build_root   # where the binaries look for their fixtures (run.sh links it)
o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
mkdir -p /tmp/amd64/partial
apt-get $o update >/dev/null
(cd .gl && apt-get $o download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
du -sh .devbin .gl
