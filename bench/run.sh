#!/usr/bin/env bash
# One command for issue 8's offline benchmarks: builds release, makes (once) a
# 1,000,000-frame rc_car log with `canodom simulate`, times `canodom replay`
# (to CSV and, #25, to MCAP),
# `canodom decode`, `wc -l` and cantools on that same file in the same run,
# then runs the codec and filter criterion benches with short measurement
# times, and writes everything to one markdown report.
#
#   bench/run.sh                 # report in target/bench-report.md
#   BENCH_DIR=/tmp/b RUNS=5 bench/run.sh
#
# Wall times are the best of $RUNS runs (least disturbed by other load);
# CPU is user+sys of that run. See bench/README.md.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
target=${CARGO_TARGET_DIR:-$root/target}
bench_dir=${BENCH_DIR:-$target/bench}
runs=${RUNS:-3}
report=${REPORT:-$target/bench-report.md}
frames=1000000
config=daemon/examples/rc_car.toml
dbc=$root/data/dbc/rc_car.dbc
mkdir -p "$bench_dir"

echo "== build (release)" >&2
CARGO_TARGET_DIR=$target cargo build --release -p canodom >&2
bin=$target/release/canodom

log=$bench_dir/rc_car_${frames}.log
if [ ! -s "$log" ] || [ "$(wc -l < "$log")" -ne "$frames" ]; then
    echo "== simulate $frames frames" >&2
    # 42 track laps ≈ 1.01 M frames; cut to exactly $frames.
    "$bin" simulate --config "$config" --log "$bench_dir/sim.log" --laps 42 >&2
    head -n "$frames" "$bench_dir/sim.log" > "$log"
    rm -f "$bench_dir/sim.log"
fi

venv=$bench_dir/venv
if [ ! -x "$venv/bin/cantools" ]; then
    echo "== cantools venv in $venv" >&2
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet cantools >&2
fi

# time_once NAME CMD...: runs CMD once, stdout to /dev/null; sets last_wall and
# keeps the fastest run's wall/cpu/rss per NAME.
declare -A best_wall best_cpu best_rss
time_once() {
    local name=$1; shift
    # /usr/bin/time's wall clock has 10 ms steps, too coarse for `wc -l`.
    t0=$(date +%s%N)
    /usr/bin/time -f '%U %S %M' -o "$bench_dir/time.txt" "$@" > /dev/null 2> "$bench_dir/$name.err"
    t1=$(date +%s%N)
    last_wall=$(awk -v a="$t0" -v b="$t1" -v o="${overhead:-0}" 'BEGIN{printf "%.4f", (b - a) / 1e9 - o}')
    read -r u s m < "$bench_dir/time.txt"
    if [ -z "${best_wall[$name]:-}" ] || awk -v a="$last_wall" -v b="${best_wall[$name]}" 'BEGIN{exit !(a<b)}'; then
        best_wall[$name]=$last_wall
        best_cpu[$name]=$(awk -v u="$u" -v s="$s" 'BEGIN{printf "%.2f", u+s}')
        best_rss[$name]=$m
    fi
}
# best_of NAME CMD...: $runs runs; sets wall/cpu/rss of the fastest.
best_of() {
    local name=$1; shift
    for _ in $(seq "$runs"); do time_once "$name" "$@"; done
    wall=${best_wall[$name]}; cpu=${best_cpu[$name]}; rss=${best_rss[$name]}
}
rate() { awk -v n="$1" -v t="$2" 'BEGIN{ printf "%.0f", n / t }'; }

echo "== timing ($runs runs each)" >&2
# What timing a process costs here (date, /usr/bin/time, fork and exec):
# ~4-5 ms on this host, a third of `wc -l`'s own time, so it is subtracted
# from every wall time below (best of $runs runs of `true`).
best_of noop true; overhead=$wall
# `wc -l` and replay alternate, so both meet the same load (on a shared
# host it changes within seconds and moved `wc -l` alone 0.010-0.020 s):
# the ratio of the best times, and the median of the run-by-run ratios.
# MCAP replay (#25) alternates with them too: its goal is a ratio to the CSV replay.
ratios=(); wc_walls=(); rp_walls=(); mc_walls=(); mc_ratios=(); mn_ratios=()
for _ in $(seq "$runs"); do
    time_once wc wc -l "$log"; w_wc=$last_wall; wc_walls+=("$last_wall")
    time_once replay "$bin" replay --config "$config" "$log" --out /dev/null; rp_walls+=("$last_wall")
    w_rp=$last_wall
    ratios+=("$(awk -v a="$last_wall" -v b="$w_wc" 'BEGIN{printf "%.2f", a / b}')")
    time_once mcap "$bin" replay --config "$config" "$log" --out /dev/null --format mcap; mc_walls+=("$last_wall")
    mc_ratios+=("$(awk -v a="$last_wall" -v b="$w_rp" 'BEGIN{printf "%.2f", a / b}')")
    time_once mcapnone "$bin" replay --config "$config" "$log" --out /dev/null --format mcap --compression none
    mn_ratios+=("$(awk -v a="$last_wall" -v b="$w_rp" 'BEGIN{printf "%.2f", a / b}')")
done
mc_wall=${best_wall[mcap]}; mc_cpu=${best_cpu[mcap]}; mc_rss=${best_rss[mcap]}
mn_wall=${best_wall[mcapnone]}; mn_cpu=${best_cpu[mcapnone]}; mn_rss=${best_rss[mcapnone]}
median() { printf '%s\n' "$@" | sort -n | awk '{a[NR] = $1} END {print a[int((NR + 1) / 2)]}'; }
mc_median=$(median "${mc_ratios[@]}"); mn_median=$(median "${mn_ratios[@]}")
# The files themselves, once each, to disk: their sizes, and what writing
# the bytes costs besides making them (the timings above write to /dev/null).
time_once csvfile "$bin" replay --config "$config" "$log" --out "$bench_dir/bench.csv"
csv_file_wall=$last_wall; csv_mb=$(du -m "$bench_dir/bench.csv" | cut -f1)
time_once mcapfile "$bin" replay --config "$config" "$log" --out "$bench_dir/bench.mcap"
mc_file_wall=$last_wall; mc_mb=$(du -m "$bench_dir/bench.mcap" | cut -f1)
time_once mcapnonefile "$bin" replay --config "$config" "$log" --out "$bench_dir/bench-none.mcap" --compression none
mn_file_wall=$last_wall; mn_mb=$(du -m "$bench_dir/bench-none.mcap" | cut -f1)
rm -f "$bench_dir/bench.csv" "$bench_dir/bench-none.mcap"
# min / median / max of a list of numbers: which of the two moved between runs.
spread() { printf '%s\n' "$@" | sort -n | awk '{a[NR] = $1} END {printf "%s / %s / %s", a[1], a[int((NR + 1) / 2)], a[NR]}'; }
wc_wall=${best_wall[wc]}; wc_cpu=${best_cpu[wc]}; wc_rss=${best_rss[wc]}
rp_wall=${best_wall[replay]}; rp_cpu=${best_cpu[replay]}; rp_rss=${best_rss[replay]}
pair_median=$(printf '%s\n' "${ratios[@]}" | sort -n | awk '{a[NR] = $1} END {print a[int((NR + 1) / 2)]}')
best_of decode "$bin" decode --dbc "$dbc" "$log"; dc_wall=$wall; dc_cpu=$cpu; dc_rss=$rss
# Memory constant in log size: the same commands on a tenth of the log.
head -n $((frames / 10)) "$log" > "$bench_dir/tenth.log"
runs_saved=$runs; runs=1
best_of replay10 "$bin" replay --config "$config" "$bench_dir/tenth.log" --out /dev/null; rp10_rss=$rss
best_of decode10 "$bin" decode --dbc "$dbc" "$bench_dir/tenth.log"; dc10_rss=$rss
runs=$runs_saved
echo "== cantools loop (Python, whole log)" >&2
ct=$("$venv/bin/python" bench/cantools_loop.py "$dbc" "$log")
ct_fps=$(python3 -c 'import json,sys; print(round(json.loads(sys.argv[1])["frames_per_s"]))' "$ct")
slice=20000
head -n $slice "$log" > "$bench_dir/slice.log"
runs_saved=$runs; runs=1
best_of cantools_cmd sh -c "'$venv/bin/cantools' decode '$dbc' < '$bench_dir/slice.log'"
runs=$runs_saved
cc_fps=$(rate $slice "$wall")

rp_fps=$(rate $frames "$rp_wall"); dc_fps=$(rate $frames "$dc_wall"); wc_fps=$(rate $frames "$wc_wall")
rp_cfps=$(rate $frames "$rp_cpu"); dc_cfps=$(rate $frames "$dc_cpu")
ratio() { awk -v a="$1" -v b="$2" 'BEGIN{printf "%.2f", a / b}'; }

echo "== criterion microbenchmarks (short)" >&2
crit_args=(--warm-up-time 0.3 --measurement-time 1 --output-format bencher)
micro=$(
    CARGO_TARGET_DIR=$target cargo bench -q -p canodom-dbc --bench decode -- "${crit_args[@]}" 2>/dev/null | grep '^test '
    CARGO_TARGET_DIR=$target cargo bench -q -p canodom-fusion --bench fusion -- "${crit_args[@]}" 2>/dev/null | grep '^test '
    CARGO_TARGET_DIR=$target cargo bench -q -p canodom-can --bench candump -- "${crit_args[@]}" 2>/dev/null | grep '^test '
    CARGO_TARGET_DIR=$target cargo bench -q -p canodom --bench csv_rows -- "${crit_args[@]}" 2>/dev/null | grep '^test '
)

{
    echo "# canodom offline benchmarks"
    echo
    echo "$(date -u '+%Y-%m-%d %H:%M UTC'), $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg); log $frames frames of rc_car.dbc ($(du -m "$log" | cut -f1) MB) from \`canodom simulate --laps 42\`; best of $runs runs; wall times are net of the $overhead s that timing a no-op process takes."
    echo
    echo "| command | wall s | frames/s (wall) | CPU s | frames/s (CPU) | peak RSS kB (1 M / 0.1 M frames) |"
    echo "|---|---:|---:|---:|---:|---:|"
    echo "| \`wc -l\` (floor: reading the bytes) | $wc_wall | $wc_fps | $wc_cpu | | $wc_rss |"
    echo "| \`canodom replay\` (EKF, CSV out) | $rp_wall | $rp_fps | $rp_cpu | $rp_cfps | $rp_rss / $rp10_rss |"
    echo "| \`canodom replay --format mcap\` (EKF, MCAP out: 9 channels, LZ4; $mc_mb MB) | $mc_wall | $(rate $frames "$mc_wall") | $mc_cpu | $(rate $frames "$mc_cpu") | $mc_rss |"
    echo "| \`canodom replay --format mcap --compression none\` ($mn_mb MB) | $mn_wall | $(rate $frames "$mn_wall") | $mn_cpu | $(rate $frames "$mn_cpu") | $mn_rss |"
    echo "| \`canodom decode\` (JSON out) | $dc_wall | $dc_fps | $dc_cpu | $dc_cfps | $dc_rss / $dc10_rss |"
    echo "| cantools loop (logreader + decode_message) | | $ct_fps | | | |"
    echo "| \`cantools decode\` command ($slice-frame slice) | | $cc_fps | | | |"
    echo
    echo "| ratio | value | goal |"
    echo "|---|---:|---|"
    echo "| replay / cantools loop (frame rate) | $(ratio "$rp_fps" "$ct_fps")x | ≥ 50x |"
    echo "| replay time / \`wc -l\` time (best / best) | $(ratio "$rp_wall" "$wc_wall")x | ≤ 10x |"
    echo "| the same, median of the $runs run-by-run ratios (alternating runs) | ${pair_median}x | ≤ 10x |"
    echo "| (wall s over the $runs runs, min / median / max: \`wc -l\` $(spread "${wc_walls[@]}"), replay $(spread "${rp_walls[@]}")) | | |"
    echo "| MCAP replay time / CSV replay time (best / best) | $(ratio "$mc_wall" "$rp_wall")x | ≤ 1.5x |"
    echo "| the same, median of the $runs run-by-run ratios; CPU time ratio | ${mc_median}x; $(ratio "$mc_cpu" "$rp_cpu")x | ≤ 1.5x |"
    echo "| MCAP uncompressed replay time / CSV replay time (best / best; median; CPU) | $(ratio "$mn_wall" "$rp_wall")x; ${mn_median}x; $(ratio "$mn_cpu" "$rp_cpu")x | ≤ 1.5x |"
    echo "| to files on disk, one run each: CSV ($csv_mb MB), MCAP LZ4 ($mc_mb MB), MCAP uncompressed ($mn_mb MB), wall s | $csv_file_wall; $mc_file_wall; $mn_file_wall | |"
    echo "| decode / cantools loop (frame rate) | $(ratio "$dc_fps" "$ct_fps")x | ≥ 10x |"
    echo "| decode / \`cantools decode\` command | $(ratio "$dc_fps" "$cc_fps")x | |"
    echo
    echo "## Criterion microbenchmarks (codec, filter, candump parser, CSV rows; 1 s each)"
    echo
    echo '```'
    echo "$micro"
    echo '```'
} > "$report"
cat "$report"
echo "report: $report" >&2
