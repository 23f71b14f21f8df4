#!/usr/bin/env bash
# A run stopped half-way and resumed from its last.ckpt, against the same run uninterrupted:
# martinez2017_res_sup on synthetic data, 2*HALF iterations, validated every HALF. The two
# summary.yaml files at the end should hold the same final_val_euler_avg (the first
# half-run's summary is printed between them).
#   benchmarks/resume_check.sh DEVICE(gpu|cpu) COMPILE(true|false) HALF
# e.g. `benchmarks/resume_check.sh gpu true 100` for a compiled run on CUDA (README,
# "What is measured on a GPU"); R= names a new scratch folder, PY= the python (default python3).
set -u
T=$1; C=$2; H=$3; N=$((2*H)); R=${R:-$(mktemp -d -t resume_check.XXXXXX)}
if [ -n "$(ls -A "$R" 2>/dev/null)" ]; then echo "R=$R is not empty: name a new folder" >&2; exit 2; fi
mkdir -p $R; echo "scratch folder: $R"
export MOTION_DATA_DIR=$R/data PYTHONUNBUFFERED=1
PY=${PY:-python3}
common="experiment=martinez2017_res_sup data=synthetic trainer=$T compile.enabled=$C val_every=$H media_every=0 trainer.enable_progress_bar=false progress_every_s=null"
t0=$(date +%s)
$PY -m src.train $common iterations=$N paths.log_dir=$R/full > $R/full.log 2>&1; echo "full rc=$? $(( $(date +%s)-t0 )) s"
$PY -m src.train $common iterations=$H paths.log_dir=$R/half > $R/half.log 2>&1; echo "half rc=$? $(( $(date +%s)-t0 )) s"
ck=$(ls $R/half/train/runs/*/*/checkpoints/last.ckpt | head -1); echo "ckpt $ck"
$PY -m src.train ckpt_path=$ck iterations=$N paths.log_dir=$R/half > $R/resume.log 2>&1; echo "resume rc=$? $(( $(date +%s)-t0 )) s"
for f in $R/full/train/runs/*/*/summary.yaml $R/half/train/runs/*/*/summary.yaml; do echo "== $f"; head -30 $f; done
grep -h -i -E "error|Traceback|resum" $R/resume.log | head -20
