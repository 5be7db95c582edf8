/*
 * A C host of the taut plugin in plugin-owned devices mode: taut opens the devices of the
 * robot configuration itself (the CANopen drives on its SocketCAN interface, the Modbus RTU
 * load cells on its serial port, the tracker on its UDP port) when the host activates it, and
 * the host only gives the cycle: it calls taut_update every period with NULL inputs, as a
 * robot controller's real-time task would. It runs the start-up (bring-up, enable, the three
 * initialisation phases, the initial estimate, the excitation, the calibration) until the
 * calibrated parameters are hot-swapped, then checks that the parameter version moved past the
 * initial estimate's. Exit status 0 on success, 1 on any failure (with the reason on stderr).
 *
 *   c-host-owned CONFIG.toml DATA_DIR [MAX_WALL_S]
 *
 * The cycle is the configuration's (`period` below must match its rt.rate_hz), paced by the
 * monotonic clock; a cycle that comes late is run late, not skipped, and taut_update gets the
 * measured time since the previous cycle (the loop's speeds are per second, not per cycle).
 * MAX_WALL_S (default 600) bounds the run.
 *
 * The test (tests/tests/vcan/vcan_plugin_owned.rs) runs it inside the QEMU VM of
 * tests/vcan/run against the simulated robot's virtual drives on vcan0. Build:
 * cc -std=c11 -I ffi/include owned.c -L target/debug -ltaut -lm
 */
/* clock_gettime and clock_nanosleep are POSIX, not C11. */
#define _POSIX_C_SOURCE 200809L
#define HOST_NAME "c-host-owned"
#include "host_util.h"

#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static void dump_status(TautPlugin *p, const char *why) {
    char json[8192];
    taut_status_json(p, json, sizeof json, NULL);
    fprintf(stderr, "c-host-owned: %s: %s\n", why, json);
}

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: %s CONFIG.toml DATA_DIR [MAX_WALL_S]\n", argv[0]);
        return 2;
    }
    const char *config = argv[1];
    const double max_wall_s = argc > 3 ? atof(argv[3]) : 600.0;
    const double period = 0.01; /* the test's configuration: rt.rate_hz = 100 */

    TautOptions opts;
    CHECK(taut_options_init(&opts));
    opts.devices = TAUT_DEVICES_PLUGIN;
    opts.data_dir = argv[2];
    TautPlugin *p = NULL;
    CHECK(taut_configure(config, TAUT_CONFIG_PATH, &opts, &p));
    /* The plugin brings its devices up here: SDO configuration and NMT start of the drives,
     * the load cells' first answers, the tracker socket. */
    CHECK(taut_activate(p));
    printf("c-host-owned: activated, the plugin owns the devices\n");

    TautCommands cmd;
    const double wall0 = wall_s();
    double next = wall0;
    double last = -period;
    uint64_t initial_version = 0, calibrated_version = 0;
    int done = 0;
    for (uint64_t k = 0; !done; k++) {
        const double now = wall_s() - wall0;
        if (now > max_wall_s) {
            dump_status(p, "no hot-swap in time");
            return 1;
        }
        /* NULL inputs: the plugin reads its own devices; the commands are what it sent. */
        CHECK(taut_update(p, now, now - last, NULL, &cmd));
        last = now;
        next += period;
        sleep_until(next);
        if (k % 10 != 0) continue;

        /* The operator's side (a non-real-time thread in a real host). */
        TautEvent ev;
        TautError e;
        while ((e = taut_poll_event(p, &ev)) == TAUT_ERROR_OK) {
            switch (ev.kind) {
            case TAUT_EVENT_KIND_MOTION_STATE:
                printf("c-host-owned: t=%7.2f s  state %s\n", ev.t_s, taut_motion_state_name(ev.motion_state));
                break;
            case TAUT_EVENT_KIND_CALIBRATION:
                printf("c-host-owned: t=%7.2f s  %s %s (version %llu)\n", ev.t_s, ev.initial ? "initial estimate" : "calibration",
                       ev.accepted ? "accepted" : "REFUSED", (unsigned long long)ev.value);
                if (!ev.accepted) {
                    dump_status(p, "a calibration was refused");
                    return 1;
                }
                if (ev.initial) initial_version = ev.value;
                else calibrated_version = ev.value;
                break;
            case TAUT_EVENT_KIND_PARAMS_SWAPPED:
                printf("c-host-owned: t=%7.2f s  parameters version %llu in use\n", ev.t_s, (unsigned long long)ev.value);
                break;
            case TAUT_EVENT_KIND_FAULT:
                dump_status(p, "safety reaction latched");
                return 1;
            default:
                break;
            }
        }
        if (e != TAUT_ERROR_NO_EVENT) fail_call("taut_poll_event", e);
        TautStatus st;
        CHECK(taut_status(p, &st));
        if (calibrated_version != 0 && st.params_version == calibrated_version && !st.swap_active) done = 1;
    }

    TautStatus st;
    CHECK(taut_status(p, &st));
    TautParams par;
    CHECK(taut_params(p, &par));
    printf("c-host-owned: hot-swapped to version %llu at t=%.2f s (initial estimate was version %llu), %llu cycles, %.1f s wall\n",
           (unsigned long long)par.version, st.t_s, (unsigned long long)initial_version, (unsigned long long)st.cycles,
           wall_s() - wall0);
    if (initial_version == 0 || par.version <= initial_version || st.params_version != par.version) {
        fprintf(stderr, "c-host-owned: the parameter version did not move past the initial estimate (%llu -> %llu, loop %llu)\n",
                (unsigned long long)initial_version, (unsigned long long)par.version, (unsigned long long)st.params_version);
        return 1;
    }
    /* Deactivating stops the devices: the drives are disabled, the plugin's threads joined. */
    CHECK(taut_deactivate(p));
    CHECK(taut_cleanup(p));
    printf("c-host-owned: deactivated\n");
    return 0;
}
