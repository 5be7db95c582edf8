/*
 * What both C hosts (host.c, owned.c) need beside taut.h: a failed call's message and exit,
 * the CHECK wrapper, and the monotonic clock to pace the cycle. HOST_NAME prefixes messages.
 * Include after defining _POSIX_C_SOURCE (clock_gettime and clock_nanosleep are POSIX).
 */
#ifndef TAUT_HOST_UTIL_H
#define TAUT_HOST_UTIL_H

#include "taut.h"

#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#ifndef HOST_NAME
#define HOST_NAME "c-host"
#endif

static void fail_call(const char *what, TautError e) {
    char msg[1024];
    taut_last_error(msg, sizeof msg);
    fprintf(stderr, HOST_NAME ": %s failed (error %d): %s\n", what, (int)e, msg);
    exit(1);
}

#define CHECK(call)                                                                                \
    do {                                                                                           \
        TautError e_ = (call);                                                                     \
        if (e_ != TAUT_ERROR_OK) fail_call(#call, e_);                                             \
    } while (0)

/* Seconds on the monotonic clock. */
static double wall_s(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Sleeps until `t` on the monotonic clock (absolute: no drift from the time a cycle took). */
static void sleep_until(double t) {
    struct timespec ts;
    ts.tv_sec = (time_t)t;
    ts.tv_nsec = (long)((t - (double)ts.tv_sec) * 1e9);
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL);
}

#endif
