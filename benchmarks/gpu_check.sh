#!/usr/bin/env bash
# On a machine with a CUDA GPU: the GPU tests, the inference speed of the depth and coverage
# networks at both presets there, and, given a folder of 30-fps frames, train-depth's speed
# for 300 steps each of the paper preset, the fast preset, the shipped fine-tune's terms (chain
# and shading prior on K) and those with the zoom term (each run's metrics.jsonl, whose
# `seconds` give the speed, lands in OUT_DIR). Usage: gpu_check.sh OUT_DIR [FRAMES_DIR].
# Needs what the learned branch imports, pycolmap included (the maps of `train-depth --maps`),
# but not Open3D, GTSAM or trimesh.
set -uo pipefail
out=$1 frames=${2:-}
mkdir -p "$out"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
python3 -c "import torch; print('torch', torch.__version__, torch.cuda.is_available())"
python3 -m pytest -q -p no:cacheprovider tests/test_device.py
echo "pytest exit status $?"
python3 benchmarks/bench_depth.py --presets fast paper --batch 16 --seconds 5 --device cuda
python3 benchmarks/bench_coverage.py --device cuda --batch 256 --frame-batch 256 --paper-batch 64
[ -n "$frames" ] || exit 0
ft=(--init learned/checkpoints/depth-fast.safetensors --set w_chain=0.3 --set chain_teacher=init
    --set w_shading=0.1 --set shading_steers=intrinsics)
train() {
  local name=$1; shift
  python3 -c "from hybrid.cli import app; app()" train-depth --data "$frames" --fps 30 \
      --steps 300 --device cuda --out "$out/$name" "$@" 2>&1 | tail -1
}
train paper --preset paper
train fast --preset fast
train finetune --preset fast "${ft[@]}"
train zoom --preset fast "${ft[@]}" --set w_zoom=0.2
