#!/usr/bin/env bash
# Do committed results rows still come out of today's code?  For each committed CSV: N of its x0 (evenly spaced
# over its rows, the row scripts' full-precision x0: kexp-results sample) re-run with the row's overrides (from
# the script that made it: results/robustness.sh for results/*.csv and results/robustness/, results/regions.sh
# for results/regions/ and its map/), condensed into sweeps/reproduce/<the CSV's path>, and compared run by run
# with the committed CSV (kexp-results compare: discrete columns exactly, cost and max |u| to --rtol, settling
# time to one step; solve times not compared).  The re-runs use a fresh model cache (a temporary $KEXP_CACHE_DIR).
#
#   results/reproduce.sh [--sample N] [--rtol R] CSV [CSV ...]   # e.g. results/*.csv results/robustness/*.csv
#
# N defaults to 10, R to 1e-6.  Exit 0 when every re-run agrees, 1 when one disagrees or a row could not be
# re-run (each named at the end), 2 on bad arguments.  $KEXP_SWEEP_JOBS workers (default 2).
set -euo pipefail
cd "$(dirname "$0")/.."
source results/sweep_lib.sh

usage() { echo "usage: results/reproduce.sh [--sample N] [--rtol R] CSV [CSV ...]" >&2; exit 2; }
N=10 RTOL=1e-6
while [ $# -gt 0 ]; do
    case $1 in
        --sample) [ $# -ge 2 ] || usage; N=$2; shift 2 ;;
        --rtol) [ $# -ge 2 ] || usage; RTOL=$2; shift 2 ;;
        --) shift; break ;;
        -*) echo "unknown option $1" >&2; usage ;;
        *) break ;;
    esac
done
[ $# -gt 0 ] || usage
[[ $N =~ ^[1-9][0-9]*$ ]] || { echo "--sample $N: give a whole number >= 1" >&2; exit 2; }

script_of() {  # CSV -> the row script that made it
    case $1 in
        results/regions/*) echo results/regions.sh ;;
        results/plants/*) echo results/plants.sh ;;
        results/robustness/*|results/*) echo results/robustness.sh ;;
        *) return 1 ;;
    esac
}
for csv in "$@"; do   # every argument checked before any sweep
    [ -f "$csv" ] || { echo "$csv: no such file (give committed CSVs, e.g. results/*.csv)" >&2; exit 2; }
    script_of "$csv" > /dev/null || { echo "$csv: not under results/; give a committed CSV" >&2; exit 2; }
    bash "$(script_of "$csv")" --overrides "$(basename "$csv" .csv)" > /dev/null || exit 2
done

# the re-runs identify with today's code into a fresh model cache of their own (removed at exit): no entry of
# an earlier run, of other code or copied in by hand can stand in for what today's code computes
KEXP_CACHE_DIR=$(mktemp -d "${TMPDIR:-/tmp}/kexp-reproduce-cache.XXXXXX")
export KEXP_CACHE_DIR
trap 'rm -rf "$KEXP_CACHE_DIR"' EXIT

FAILED=()
for csv in "$@"; do
    row=$(basename "$csv" .csv) rel=${csv#results/}
    dest=sweeps/reproduce/$(dirname "$rel")
    mapfile -t ov < <(bash "$(script_of "$csv")" --overrides "$row")
    x0=$(kexp-results sample "$csv" "$N")
    rm -f "$dest/$row.csv"       # an earlier re-run's CSV must not be compared
    sweep_row "$row" "sweeps/reproduce/sweeps/${rel%.csv}" "$dest" "$x0" "${ov[@]}"
    if [ ! -f "$dest/$row.csv" ]; then
        FAILED+=("$csv (no re-run: see sweeps/reproduce/sweeps/${rel%.csv}.log)"); continue
    fi
    kexp-results compare "$csv" "$dest/$row.csv" --rtol "$RTOL" || FAILED+=("$csv")
done
if [ ${#FAILED[@]} -gt 0 ]; then
    echo "== not reproduced (${#FAILED[@]} of $#):"; printf '   %s\n' "${FAILED[@]}"; exit 1
fi
echo "== all $# rows reproduced ($N x0 each)"
