#!/usr/bin/env bash
# On the CPU machine (with network to PyPI), from the repository root: what benchmarks/gpu_check.sh carries to a
# bare GPU machine that has its own PyTorch but no network. Both folders are git-ignored (.git/info/exclude).
#   .whl/             cp312 wheels of arcsem's dependencies the GPU image lacks (35 MB; not pycolmap, 38 MB: the
#                     scene comes ready-made). imageio-ffmpeg 0.5.1 (27 MB, ffmpeg 4.2) rather than the newest
#                     (0.8.1, 68 MB, over the carry limit with the rest): the orbit videos are MP4s, as a GPU user's
#                     are, not the GIF fallback (4.5 s more of the demo where there is no ffmpeg); py-spy (3 MB)
#                     for DEMO_PYSPY=1
#   .gpu/scene.tar.xz the built-in scene as `make demo` makes it (11 MB)
set -euo pipefail
mkdir -p .whl .gpu
PLAT="--only-binary=:all: --python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux2010_x86_64 --platform manylinux_2_5_x86_64 --platform any"
for pkg in hydra-core==1.3.8 omegaconf==2.3.1 hydra-joblib-launcher==1.2.0 hydra-submitit-launcher==1.2.0 \
           submitit==1.5.4 lpips==0.1.4 trimesh==5.2.0 plyfile==1.1.5 gsplat==1.5.3 imageio-ffmpeg==0.5.1 py-spy==0.4.3; do
  python3 -m pip download -q --no-deps $PLAT -d .whl "$pkg"
done
python3 -m pip wheel -q --no-deps -w .whl antlr4-python3-runtime==4.9.3
ARCSEM_CACHE=$PWD/.gpu/cache .venv/bin/arcsem experiment=demo stage=check hydra.run.dir=/tmp/arcsem_gpu_prepare >/dev/null
tar -C .gpu/cache -cf - scenes | xz -3 -T2 > .gpu/scene.tar.xz
du -sh .whl .gpu/scene.tar.xz
