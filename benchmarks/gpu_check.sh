#!/usr/bin/env bash
# On a machine with a CUDA GPU: the GPU tests, then train-depth's speed there for 300 steps
# each of the paper preset, the fast preset, the shipped fine-tune's terms (chain and shading
# prior on K) and those with the zoom term. Usage: gpu_check.sh FRAMES_DIR OUT_DIR (a folder
# of 30-fps frames; each run's metrics.jsonl, whose `seconds` give the speed, lands in OUT_DIR).
# Needs what the learned branch imports, pycolmap included (the maps of `train-depth --maps`),
# but not Open3D or GTSAM: the coverage networks' GPU test, which imports the pipeline, is
# left out.
set -uo pipefail
frames=$1 out=$2
mkdir -p "$out"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
python3 -c "import torch; print('torch', torch.__version__, torch.cuda.is_available())"
python3 -m pytest -q -p no:cacheprovider tests/test_device.py -k "not coverage_networks"
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
