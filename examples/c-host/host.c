/*
 * A C host of the taut plugin, in host-owned devices mode: it owns a (simulated) robot, reads
 * its sensors into TautInputs every cycle, calls taut_update, and applies the TautCommands to
 * the drives. It runs the whole start-up (enable, three initialisation phases, initial
 * estimate, excitation, calibration) until the calibrated parameters are hot-swapped, then
 * checks that the parameter version moved past the initial estimate's and that every anchor
 * coordinate is within 4.46 standard uncertainties (plus 0.2 mm of encoder quantisation) of the
 * simulated site's truth (4.46: Bonferroni over 12 coordinates for a chance failure of 1e-4
 * with a right covariance; a flat 4 failed 7.6e-4 of runs). Exit status 0 on success, 1 on any failure (with the reason on stderr).
 *
 *   c-host CONFIG.toml DATA_DIR [SEED [SPEED]]
 *
 * SPEED: simulated seconds per wall-clock second (default 1; 0 = as fast as the CPU goes).
 * The calibrator runs on its own thread in wall-clock time, so a moderate speed-up keeps the
 * start-up's timing realistic while a test runs in less time.
 *
 * Build (see ffi/tests/hosts.rs): `cargo build -p taut-ffi --features sim` (the taut_sim_*
 * functions; the default library is the robot's, without the simulator), then
 * cc -std=c11 -I ffi/include host.c -L target/debug -ltaut
 */
/* clock_gettime and clock_nanosleep are POSIX, not C11. */
#define _POSIX_C_SOURCE 200809L
#define HOST_NAME "c-host"
#include "host_util.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

/* The boundary refuses what it must: NULL pointers and calls in the wrong state. */
static int check_refusals(TautPlugin *p) {
    TautInputs in;
    TautCommands cmd;
    memset(&in, 0, sizeof in);
    TautError e = taut_update(p, 0.0, 0.002, &in, &cmd);
    if (e != TAUT_ERROR_WRONG_STATE) {
        char msg[512];
        taut_last_error(msg, sizeof msg);
        fprintf(stderr, "c-host: taut_update before taut_activate was not refused as WRONG_STATE: error %d (%s)\n", (int)e, msg);
        return 1;
    }
    if (taut_update(p, 0.0, 0.002, NULL, &cmd) != TAUT_ERROR_NULL_POINTER) {
        fprintf(stderr, "c-host: taut_update with NULL inputs was not refused\n");
        return 1;
    }
    if (taut_status(NULL, NULL) != TAUT_ERROR_NULL_POINTER) {
        fprintf(stderr, "c-host: taut_status(NULL) was not refused\n");
        return 1;
    }
    char msg[256];
    if (taut_last_error(msg, sizeof msg) == 0 || strstr(msg, "NULL") == NULL) {
        fprintf(stderr, "c-host: no message for the NULL handle: \"%s\"\n", msg);
        return 1;
    }
    return 0;
}

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: %s CONFIG.toml DATA_DIR [SEED [SPEED]]\n", argv[0]);
        return 2;
    }
    const char *config = argv[1];
    const uint64_t seed = argc > 3 ? strtoull(argv[3], NULL, 10) : 1;
    const double speed = argc > 4 ? atof(argv[4]) : 1.0;
    const double period = 0.002;  /* the configuration's rt.rate_hz = 500 */
    /* The calibrator runs in wall-clock time: on a loaded machine it takes longer, and at SPEED
     * 4 each wall second is 4 simulated ones. 3600 s = 900 s of wall at speed 4 (ffi/tests/hosts.rs's
     * own limit): a timeout, not a requirement. */
    const double max_sim_s = 3600.0;

    TautSim *sim = NULL;
    CHECK(taut_sim_new(config, seed, &sim));
    TautSimTruth truth;
    CHECK(taut_sim_truth(sim, &truth));

    TautOptions opts;
    CHECK(taut_options_init(&opts));
    opts.devices = TAUT_DEVICES_HOST;
    opts.data_dir = argv[2];
    TautPlugin *p = NULL;
    CHECK(taut_configure(config, TAUT_CONFIG_PATH, &opts, &p));
    if (check_refusals(p)) return 1;
    CHECK(taut_activate(p));

    TautInputs in;
    TautCommands cmd;
    double now = 0.0;
    const double wall0 = wall_s();
    uint64_t initial_version = 0, calibrated_version = 0;
    int done = 0;
    for (uint64_t k = 0; now < max_sim_s && !done; k++) {
        CHECK(taut_sim_read(sim, now, &in));
        CHECK(taut_update(p, now, period, &in, &cmd));
        CHECK(taut_sim_write(sim, now, period, &cmd));
        now += period;
        if (speed > 0.0) sleep_until(wall0 + now / speed);
        if (k % 50 != 0) continue;

        /* The operator's side (a non-real-time thread in a real host). */
        TautEvent ev;
        TautError e;
        while ((e = taut_poll_event(p, &ev)) == TAUT_ERROR_OK) {
            switch (ev.kind) {
            case TAUT_EVENT_KIND_MOTION_STATE:
                printf("c-host: t=%7.2f s  state %s\n", ev.t_s, taut_motion_state_name(ev.motion_state));
                break;
            case TAUT_EVENT_KIND_CALIBRATION:
                printf("c-host: t=%7.2f s  %s %s (version %llu)\n", ev.t_s, ev.initial ? "initial estimate" : "calibration",
                       ev.accepted ? "accepted" : "REFUSED", (unsigned long long)ev.value);
                if (!ev.accepted) {
                    char json[4096];
                    taut_status_json(p, json, sizeof json, NULL);
                    fprintf(stderr, "c-host: a calibration was refused: %s\n", json);
                    return 1;
                }
                if (ev.initial) initial_version = ev.value;
                else calibrated_version = ev.value;
                break;
            case TAUT_EVENT_KIND_PARAMS_SWAPPED:
                printf("c-host: t=%7.2f s  parameters version %llu in use\n", ev.t_s, (unsigned long long)ev.value);
                break;
            case TAUT_EVENT_KIND_FAULT: {
                char json[4096];
                taut_status_json(p, json, sizeof json, NULL);
                fprintf(stderr, "c-host: safety reaction latched at t=%.2f s: %s\n", ev.t_s, json);
                return 1;
            }
            default:
                break;
            }
        }
        if (e != TAUT_ERROR_NO_EVENT) fail_call("taut_poll_event", e);
        TautStatus st;
        CHECK(taut_status(p, &st));
        if (calibrated_version != 0 && st.params_version == calibrated_version && !st.swap_active) done = 1;
    }
    if (!done) {
        char json[4096];
        taut_status_json(p, json, sizeof json, NULL);
        fprintf(stderr, "c-host: no hot-swap within %.0f s of simulated time: %s\n", max_sim_s, json);
        return 1;
    }

    TautStatus st;
    CHECK(taut_status(p, &st));
    TautParams par;
    CHECK(taut_params(p, &par));
    printf("c-host: hot-swapped to version %llu at t=%.2f s (initial estimate was version %llu), %llu cycles, "
           "%llu samples dropped, largest swap step %.3f mm, %.1f s wall\n",
           (unsigned long long)par.version, st.t_s, (unsigned long long)initial_version, (unsigned long long)st.cycles,
           (unsigned long long)st.samples_dropped, st.max_swap_step_m * 1e3, wall_s() - wall0);
    int bad = 0;
    if (initial_version == 0 || par.version <= initial_version || st.params_version != par.version) {
        fprintf(stderr, "c-host: the parameter version did not move past the initial estimate (%llu -> %llu, loop %llu)\n",
                (unsigned long long)initial_version, (unsigned long long)par.version, (unsigned long long)st.params_version);
        bad = 1;
    }
    for (uint32_t j = 0; j < par.n_cables; j++) {
        double worst = 0.0;
        for (int i = 0; i < 3; i++) {
            double err = fabs(par.anchors_m[j][i] - truth.anchors_m[j][i]);
            double lim = 4.46 * par.anchor_sigma_m[j][i] + 2e-4;
            if (!(err < lim)) {
                fprintf(stderr, "c-host: anchor %u[%d] off by %.2f mm, sigma %.2f mm\n", j, i, err * 1e3, par.anchor_sigma_m[j][i] * 1e3);
                bad = 1;
            }
            if (err > worst) worst = err;
        }
        printf("c-host: anchor %u off the truth by at most %.2f mm per axis (sigma %.2f %.2f %.2f mm)\n", j, worst * 1e3,
               par.anchor_sigma_m[j][0] * 1e3, par.anchor_sigma_m[j][1] * 1e3, par.anchor_sigma_m[j][2] * 1e3);
    }
    CHECK(taut_deactivate(p));
    CHECK(taut_cleanup(p));
    taut_sim_free(sim);
    if (bad) return 1;
    printf("c-host: ok\n");
    return 0;
}
