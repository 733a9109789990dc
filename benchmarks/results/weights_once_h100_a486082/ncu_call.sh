#!/usr/bin/env bash
set -uo pipefail
bash .gpu/b/install.sh
rm -rf /tmp/aw && mkdir -p /tmp/aw && cp -r aquarium_warp benchmarks tests pyproject.toml /tmp/aw/ && cp -r kernels training /tmp/aw/aquarium_warp/ && cp .gpu/b/lossprobe.py /tmp/aw/  # (this folder's ncu_probe.py)
export PYTHONPATH=/tmp/site:/tmp/aw GIT_PYTHON_REFRESH=quiet NCCL_NVLS_ENABLE=0 PYTHONUNBUFFERED=1
R=/tmp/p13 && rm -rf $R && mkdir -p $R && cd /tmp/aw
trap 'tar czf $OUT/p13.tgz -C /tmp p13; ls -la $OUT' EXIT
NCU=$(command -v ncu || echo /usr/local/cuda/bin/ncu); echo "ncu: $NCU"
timeout 120 python lossprobe.py 2>&1 | grep -v "^Warp\|^   \|^Module" | tail -12
timeout 400 $NCU --kernel-name regex:"_(actor|critic)_loss_kernel" --launch-skip 4 --launch-count 2 \
  --section SpeedOfLight --section ComputeWorkloadAnalysis --section MemoryWorkloadAnalysis --section WarpStateStats \
  --section Occupancy --section LaunchStats --section SchedulerStats --section InstructionStats \
  python lossprobe.py > $R/ncu.txt 2>&1; echo "ncu rc=$?"
grep -v "^Warp\|^   CUDA\|^   Dev\|^   Kernel\|^     \"\|^Module" $R/ncu.txt | tail -230
