#!/usr/bin/env bash
# The sweeps behind the README's far-region and tight-bound tables (issue 13): 100 initial conditions per row from
# np.random.default_rng(42).uniform(-2, 2, (2, 100)) -- the whole data region, not only [-1, 1]² -- each condensed
# into results/regions/<row>.csv.
#
#   results/regions.sh ROW [ROW ...]     # e.g. vanderpol_lmpc pendulum-u1_nmpc
#   results/regions.sh --list            # every row this script knows
#   results/regions.sh --map ROW [...]    # the region maps' 400 x0: 300 more from default_rng(43) over [-2, 2]²,
#                                         # into results/regions/map/ROW.csv with the row's 100 (run those first)
#   results/regions.sh --overrides ROW   # the row's kexp overrides, one per line (results/reproduce.sh)
#
# Row names: <system>[-uN]_<controller>: the working preset +experiment=<system>; -uN: the input bound |u| ≤ N
# (controller.u_min=-N, controller.u_max=N) for every controller of the row, oracle included; controller lmpc
# (the preset's), lqr (saturated LQR on the true linearisation) or nmpc (the true-model oracle, oracle_horizon in
# results/sweep_lib.sh: 20 steps, 100 for cart_pendulum).
# The table: kexp-results table results/regions/*.csv; the maps: kexp-figures roa ... --oracle ..._nmpc.csv.
set -euo pipefail
cd "$(dirname "$0")/.."
source results/sweep_lib.sh

overrides() {  # ROW -> the kexp overrides of that row
    local row=$1 head=${1%_*} ctrl=${1##*_}
    local system=${head%%-*} out=()
    out+=("+experiment=$system")
    case $ctrl in
        lmpc) ;;
        lqr) out+=(controller=lqr) ;;
        nmpc) out+=(controller=nmpc "controller.horizon=$(oracle_horizon "$system")") ;;
        *) echo "unknown controller in row $row" >&2; return 2 ;;
    esac
    if [[ $head == *-u* ]]; then
        local bound=${head#*-u}
        [[ $bound =~ ^[0-9]+(\.[0-9]+)?$ ]] || { echo "bad bound in row $row" >&2; return 2; }
        out+=("controller.u_min=-$bound" "controller.u_max=$bound")
    fi
    printf '%s\n' "${out[@]}"
}

if [ "${1:-}" = "--overrides" ]; then   # the row's kexp overrides, one per line (results/reproduce.sh)
    [ $# = 2 ] || { echo "usage: $0 --overrides ROW" >&2; exit 2; }
    overrides "$2"; exit
fi

X0=$(x0_list -2 2)      # after --overrides, which needs no x0

ROWS=()
for s in vanderpol pendulum; do
    for c in lmpc lqr nmpc; do ROWS+=("${s}_$c"); done
done

if [ "${1:-}" = "--list" ]; then printf '%s\n' "${ROWS[@]}" "(and <system>-uN_<controller> for a bound N)"; exit 0; fi
MAP=0
if [ "${1:-}" = "--map" ]; then MAP=1; shift; X0=$(x0_list -2 2 43 300); fi
for row in "$@"; do
    mapfile -t ov < <(overrides "$row")
    [ ${#ov[@]} -gt 0 ] || exit 2     # overrides said why on stderr
    if [ $MAP = 0 ]; then
        sweep_row "$row" "sweeps/regions/$row" results/regions "$X0" "${ov[@]}"
        continue
    fi
    [ -f "results/regions/$row.csv" ] || { echo "no results/regions/$row.csv: run results/regions.sh $row first" >&2; exit 2; }
    more=results/regions/map/300/$row.csv
    rm -f "$more"      # a failed collect must not leave an earlier sweep's x0 to be merged
    sweep_row "$row" "sweeps/regions/map/$row" results/regions/map/300 "$X0" "${ov[@]}"
    [ -f "$more" ] || continue
    if [ "$(head -n1 "$more")" != "$(head -n1 "results/regions/$row.csv")" ]; then
        echo "$more and results/regions/$row.csv have different columns: not merged" >&2; exit 2
    fi
    { cat "results/regions/$row.csv"; tail -n +2 "$more"; } > "results/regions/map/$row.csv"
    echo "== $row: $(($(wc -l < "results/regions/map/$row.csv") - 1)) x0 in results/regions/map/$row.csv"
done
