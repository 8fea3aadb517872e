# Shared by results/robustness.sh, results/regions.sh and the plant rows' scripts (sourced, not run): the initial
# conditions of a results row and the sweep that condenses one row into a CSV.

# x0_list LOW HIGH [SEED N]: the N initial conditions np.random.default_rng(SEED).uniform(LOW, HIGH, (2, N)).T
# (SEED 42, N 100 unless given) as one Hydra list value (kexp.results.reproduce: kexp-results sample knows them too)
x0_list() {
    python -c "from kexp.results.reproduce import generated_x0, hydra_list; print(hydra_list(generated_x0(${3:-42}, $1, $2, ${4:-100})))"
}

# oracle_horizon SYSTEM: the NMPC oracle's horizon in steps.  20 (0.2 s, with the true linearisation's LQR
# cost-to-go as terminal cost) except for cart_pendulum: there it fails to stabilise 10 of the results' 100 x0
# in [-1, 1]² (J ≈ 20–98): where cos(x1) has halved the input's grip the quadratic terminal cost misjudges the
# state.  With 100 steps it stabilises all and costs the least of all controllers on each.
oracle_horizon() {
    case $1 in
        cart_pendulum) echo 100 ;;
        *) echo 20 ;;
    esac
}

# sweep_row ROW SWEEP_DIR DEST X0 OVERRIDE...: a multirun over the x0 of X0 of kexp with the overrides into SWEEP_DIR (its
# output in SWEEP_DIR.log), condensed into DEST/ROW.csv.  No MCAP log and no Rerun recording per run: the tables
# and maps need only each run's summary.json.  $KEXP_SWEEP_JOBS workers (default 2).
sweep_row() {
    local row=$1 dir=$2 dest=$3 x0=$4
    shift 4
    rm -rf "$dir"
    mkdir -p "$(dirname "$dir")" "$dest"
    echo "== $row: $*"
    kexp --multirun hydra/launcher=joblib hydra.launcher.n_jobs="${KEXP_SWEEP_JOBS:-2}" logging.rrd=false \
        logging.mcap=false "sim.x0=$x0" "$@" hydra.sweep.dir="$dir" > "$dir.log" 2>&1 || true
    kexp-results collect "$dir" "$row" -o "$dest" || echo "== $row: no results (see $dir.log)"
}

# x0_box 'L1,…,Ln' 'H1,…,Hn' [SEED N]: the N initial conditions of n states drawn from the box [L_i, H_i] state by
# state (np.random.default_rng(SEED), SEED 42, N 100 unless given; L_i = H_i fixes state i, e.g. zero velocities)
# as one Hydra list value (kexp-results x0; kexp.results.reproduce.generated_x0).  x0_box '-1,-1' '1,1' prints what
# x0_list -1 1 prints.
x0_box() {
    kexp-results x0 --seed "${3:-42}" -n "${4:-100}" -- "$1" "$2"     # --: a corner may start with '-' 
}
