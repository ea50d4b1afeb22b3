#!/usr/bin/env bash
# The suite benchmark on the lent GPU machine, which has no network (docs/gpu.md "A GPU lease in one call").
#
# Run there from the checkout's root, with `.device` carried (made here by `python scripts/device_kit.py`):
#   bash scripts/device_suite.sh --wait 560 -- --preset gpu --episodes 30 \
#     --tasks '[lift,stack,pick_place,nut_assembly,door]'
# and, made at once after it, the lease's last call (see --final below):
#   bash scripts/device_suite.sh --final --wait 200 -- --preset gpu --episodes 30 \
#     --tasks '[lift,stack,pick_place,nut_assembly,door]'
# Several runs share the card (and the one collection) when their bench_suite arguments are separated by `---`:
#   bash scripts/device_suite.sh --wait 560 -- --preset gpu --tasks '[...]' --- --preset gpu --tasks '[...]' --seeds '[1]'
#
# The first call unpacks LeRobot, robosuite, MuJoCo and sigma onto PYTHONPATH and the GL loaders onto /, then starts
# the pipeline in its own session (it outlives the call while the machine is held): one collection with the first
# run's arguments (`--stop_after collect`), then every run's `python -m benchmarks.bench_suite --device cuda
# --workers 16 --publish false` at once (training, closed loop, diagnosis). Each call waits up to --wait seconds
# and leaves the progress in $OUT/status.txt; a call made while the pipeline runs only waits. Once it has finished,
# the call also leaves in $OUT the logs and every run's results, diagnostics and last checkpoint (no optimiser
# state) as one tar in parts of 15 MiB (`python scripts/device_kit.py --command unpack` joins them here). The
# machine goes back 30 s after a call ends, so a second call must follow the first at once.
#
# `--final` marks the lease's last call: if the pipeline has not finished when its wait ends, the call still returns
# what it has written so far (the logs, each run's results and diagnostics so far, and its latest checkpoint), which
# the CPU machine can score, instead of leaving it on a machine about to go back. Give that call a --wait that leaves
# a minute of the lease for the packing and the transfer.
set -euo pipefail
cd "$(dirname "$0")/.."
: "${OUT:?OUT must name the folder whose files come back}"
wait_s=560
final=false
while (($#)); do
  case $1 in
    --wait) wait_s=$2; shift 2 ;;
    --final) final=true; shift ;;
    --) shift; break ;;
    *) break ;;
  esac
done
kit=${KIT:-.device}            # what scripts/device_kit.py packed (a test packs elsewhere)
state=${STATE:-/tmp/sigma_device}  # outlives the call while the machine is held
suite=$kit/suite
t0=$(date +%s)

if [[ ! -f $state/started ]]; then
  [[ -f $kit/site.tar.xz ]] || { echo "device_suite: $kit/site.tar.xz is missing: carry $kit" >&2; exit 1; }
  rm -rf "$state" && mkdir -p "$state/logs"
  # GL loaders, where there are none (grep reads all of ldconfig's list: with -q, pipefail could see a SIGPIPE)
  if command -v ldconfig >/dev/null && ! ldconfig -p | grep libEGL.so.1 >/dev/null; then
    for f in "$kit"/gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
  fi
  tar -xJf "$kit/site.tar.xz" -C "$state"
  {
    echo "export PYTHONPATH=$state/site${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1 MUJOCO_GL=egl"
    vendor=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json  # the driver's EGL, where it is mounted
    [[ -f $vendor ]] && echo "export __EGL_VENDOR_LIBRARY_FILENAMES=$vendor"
    echo "export SIGMA_TEXT_FEATURES=$(realpath "$kit")/text_features.safetensors HF_HUB_OFFLINE=1 TOKENIZERS_PARALLELISM=false"
  } >"$state/env.sh"
  # One line of quoted bench_suite arguments per run.
  run_line() { if (($#)); then printf '%q ' "$@"; fi; echo; }
  current=()
  for arg in "$@"; do
    if [[ "$arg" == "---" ]]; then run_line "${current[@]}" >>"$state/runs"; current=(); else current+=("$arg"); fi
  done
  run_line "${current[@]}" >>"$state/runs"
  cat >"$state/pipeline.sh" <<EOF
set -uo pipefail
source $state/env.sh
cd $PWD
bench="python3 -m benchmarks.bench_suite --output_dir $suite --device cuda --workers 16 --publish false"
s=\$(date +%s)
echo "setup: \$(python3 -c 'import torch; print(torch.cuda.get_device_name())')" >>$state/status.txt
eval "\$bench \$(head -n 1 $state/runs) --stop_after collect" >$state/logs/collect.log 2>&1 \
  || { echo "collection failed after \$(( \$(date +%s) - s )) s" >>$state/status.txt; echo 1 >$state/done; exit 1; }
echo "collected in \$(( \$(date +%s) - s )) s" >>$state/status.txt
i=0; pids=()
while read -r line; do
  eval "\$bench \$line" >$state/logs/run_\$i.log 2>&1 &
  pids+=(\$!); i=\$((i + 1))
done <$state/runs
code=0
for pid in "\${pids[@]}"; do wait "\$pid" || code=\$?; done
echo "runs finished in \$(( \$(date +%s) - s )) s from the start, exit \$code" >>$state/status.txt
echo \$code >$state/done
EOF
  touch "$state/started"
  setsid nohup bash "$state/pipeline.sh" >"$state/logs/pipeline.log" 2>&1 </dev/null &
  echo "device_suite: unpacked and started in $(( $(date +%s) - t0 )) s" | tee -a "$state/status.txt"
fi

while [[ ! -f $state/done ]] && (( $(date +%s) - t0 < wait_s )); do sleep 5; done
for log in "$state"/logs/*.log; do echo "== $log"; tail -n 4 "$log"; done >>"$state/status.txt" 2>/dev/null || true
cp "$state/status.txt" "$OUT/status.txt"
if [[ ! -f $state/done ]]; then
  if ! $final; then
    echo "device_suite: still running after this call's $wait_s s; call again at once"
    exit 0
  fi
  echo "device_suite: --final: the pipeline is still running; returning what it has written so far" \
    | tee -a "$OUT/status.txt"
fi

# The logs, and each run's results, diagnostics, training log and last checkpoint (not its optimiser state).
mkdir -p "$suite"
rm -rf "$suite/logs"
cp -r "$state/logs" "$suite/logs"
cd "$suite"
shopt -s nullglob
files=(logs)
for run in runs/*/; do
  run=${run%/}
  last=$run/train/checkpoints/last
  while IFS= read -r f; do files+=("$f"); done < <(find "$run" -path "$run/train/checkpoints" -prune -o -type f -print)
  if [[ -L $last ]]; then files+=("$last" "$run/train/checkpoints/$(readlink "$last")/pretrained_model"); fi
done
# A run still writing may change a file while it is read (tar's exit 1): what was read is still worth returning.
{ tar -cf - --warning=no-file-changed "${files[@]}" || (($? == 1)); } | split -b 15m - "$OUT/runs.tar.part-"
ls -la "$OUT"
took=$(( $(date +%s) - $(stat -c %Y "$state/started") ))
if [[ -f $state/done ]]; then
  echo "device_suite: done (exit $(cat "$state/done")) after $took s"
else
  echo "device_suite: partial, returned after $took s with the pipeline still running"
fi
