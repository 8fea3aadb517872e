#!/usr/bin/env bash
# The sweeps behind the README's robustness table (issue 12): 100 initial conditions per row,
# np.random.default_rng(42).uniform(-1, 1, (2, 100)), each condensed into results/robustness/<system>_<row>.csv
# (the unperturbed rows <system>_lmpc|lqr|nmpc into results/, the main results table's).
#
#   results/robustness.sh ROW [ROW ...]     # e.g. vanderpol_lmpc-reg-noise1 pendulum_nmpc-noise3
#   results/robustness.sh --list            # the rows it runs for the README's robustness table (any row of
#                                           # the grammar below runs)
#   results/robustness.sh --overrides ROW   # the row's kexp overrides, one per line (results/reproduce.sh)
#
# Row names: <system>_<controller>[-hN][-reg][-noise1|-noise3][-dnN][-mnN][-raw|-sgN][-iv][-mu0.8|...|-c0.012]; -hN: the
# oracle's horizon in steps (controller nmpc only; rows <system>_nmpc-hN go to results/horizon/); -dnN: N % noise
# on the data only, unsmoothed; -mnN: N % measurement noise in the closed loop only, each x0 its own draw
# (sim.noise.per_x0); -iv: the instrumental-variables estimator (identification.estimator=iv); -reg: B, b regressed
# from excited data (G unknown); -noiseN: N % Gaussian noise (of the data's RMS) on the data and the closed loop's
# measurements, the data smoothed before identification (data.smooth.window=7, or N with -sgN) unless -raw; mu…/c…: the
# plant's parameter (Van der Pol μ = 1, pendulum c = 0.01) 20 % off the data's system.  Controllers: lmpc (the working
# preset), paper-lmpc (the paper's recipe, +experiment=paper_<system>), lqr, nmpc (the true-model oracle).
# The table (`kexp-results robustness results/*.csv`) reads the conditions from the runs' summaries, not from
# these names.
set -euo pipefail
cd "$(dirname "$0")/.."
source results/sweep_lib.sh

overrides() {  # ROW -> the kexp overrides of that row
    local row=$1 system=${1%_*} rest=${1##*_}
    local ctrl=${rest%%-*} out=("+experiment=$system")
    [[ $rest == paper-lmpc* ]] && ctrl=paper-lmpc      # the paper's recipe, +experiment=paper_<system>
    local hz=""
    [[ $rest =~ -h([0-9]+)(-|$) ]] && hz=${BASH_REMATCH[1]}   # -hN: the oracle's horizon, N steps
    case $ctrl in
        lmpc) ;;
        paper-lmpc) out=("+experiment=paper_$system") ;;
        lqr) out+=(controller=lqr) ;;
        nmpc) out+=(controller=nmpc "controller.horizon=${hz:-$(oracle_horizon "$system")}") ;;
        *) echo "unknown controller in row $row" >&2; return 2 ;;
    esac
    local tok smooth=0 raw=0 win=7
    IFS=- read -ra toks <<< "${rest#"$ctrl"}"
    for tok in "${toks[@]}"; do
        case $tok in
            "") ;;
            reg) out+=("data.excitation={low: -1.0, high: 1.0, hold: 10}" identification.inputs=regression) ;;
            noise1) out+=(data.noise.std=0.01 sim.noise.std=0.01); smooth=1 ;;
            noise3) out+=(data.noise.std=0.03 sim.noise.std=0.03); smooth=1 ;;
            dn1|dn3|dn5) out+=("data.noise.std=0.0${tok#dn}"); raw=1 ;;   # the data's noise only, unsmoothed
            mn1|mn3) out+=("sim.noise.std=0.0${tok#mn}" sim.noise.per_x0=true) ;;   # the loop's only, a draw per x0
            iv) out+=(identification.estimator=iv) ;;
            h[0-9]*) [ "$ctrl" = nmpc ] || { echo "token $tok (the oracle's horizon) needs controller nmpc in row $row" >&2; return 2; } ;;
            raw) raw=1 ;;
            sg[0-9]*) win=${tok#sg} ;;
            mu0.8|mu1.2) out+=("+sim.plant_params.mu=${tok#mu}") ;;
            c0.008|c0.012) out+=("+sim.plant_params.c=${tok#c}") ;;
            *) echo "unknown token $tok in row $row" >&2; return 2 ;;
        esac
    done
    # noisy data are smoothed before identification (data.smooth), unless the row says raw
    [ $smooth = 1 ] && [ $raw = 0 ] && out+=("data.smooth.window=$win")
    printf '%s\n' "${out[@]}"
}

if [ "${1:-}" = "--overrides" ]; then   # the row's kexp overrides, one per line (results/reproduce.sh)
    [ $# = 2 ] || { echo "usage: $0 --overrides ROW" >&2; exit 2; }
    overrides "$2"; exit
fi

X0=$(x0_list -1 1)      # after --overrides, which needs no x0

ROWS=()
for s in vanderpol pendulum; do
    if [ $s = vanderpol ]; then lo=mu0.8 hi=mu1.2; else lo=c0.008 hi=c0.012; fi
    for c in lmpc lmpc-reg; do for n in "" -noise1 -noise3; do ROWS+=("${s}_$c$n"); done; done
    ROWS+=("${s}_lmpc-reg-$lo" "${s}_lmpc-reg-$hi" "${s}_lmpc-reg-noise1-raw")
    [ $s = vanderpol ] && ROWS+=("${s}_lmpc-reg-noise1-sg21")
    for c in lqr nmpc; do
        for v in -noise1 -noise3 "-$lo" "-$hi"; do ROWS+=("${s}_$c$v"); done
    done
done

# issue 34: raw 3 % data noise and 1 % measurement noise (a draw per x0), G regressed, least squares and IV, against
# the LQR and the oracle under the same measurement noise
for s in vanderpol pendulum; do
    ROWS+=("${s}_lmpc-reg-dn3-mn1" "${s}_lmpc-reg-dn3-mn1-iv" "${s}_lqr-mn1" "${s}_nmpc-mn1")
done

# the cart pendulum (G varies with x; README "A state-dependent input matrix"): G regressed, and with 1 % noise
ROWS+=(cart_pendulum_lmpc-reg cart_pendulum_lmpc-reg-noise1 cart_pendulum_lqr-noise1 cart_pendulum_nmpc-noise1)

if [ "${1:-}" = "--list" ]; then printf '%s\n' "${ROWS[@]}"; exit 0; fi
for row in "$@"; do
    mapfile -t ov < <(overrides "$row")
    [ ${#ov[@]} -gt 0 ] || exit 2     # overrides said why on stderr
    dest=results/robustness
    [[ $row =~ ^[a-z_]+_(paper-lmpc|lmpc|lqr|nmpc)$ ]] && dest=results
    [[ $row =~ ^[a-z_]+_nmpc-h[0-9]+$ ]] && dest=results/horizon     # the long-horizon oracle: results/horizon.md
    sweep_row "$row" "sweeps/$row" "$dest" "$X0" "${ov[@]}"
done
