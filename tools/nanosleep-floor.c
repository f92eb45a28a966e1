/* The floor of this computer's timing: a plain C loop that wakes every CYCLE_US with
 * clock_nanosleep(TIMER_ABSTIME) on CLOCK_MONOTONIC, as pkm-plc's cyclic thread does, and prints
 * how late each wake-up was (p50, p99, max in µs). Run it beside `pkm-plc bench` in the same minute:
 * what both show is the machine's (a VM's hypervisor, the kernel), what pkm-plc adds is the rest.
 *
 *   cc -O2 -o target/nanosleep-floor tools/nanosleep-floor.c
 *   target/nanosleep-floor SECONDS [CYCLE_US] [fifo]
 */
#define _GNU_SOURCE
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>

static int cmp(const void *a, const void *b) {
    long x = *(const long *)a, y = *(const long *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: %s SECONDS [CYCLE_US] [fifo]\n", argv[0]);
        return 2;
    }
    double seconds = atof(argv[1]);
    long cycle_ns = (argc > 2 ? atol(argv[2]) : 10000) * 1000L;
    int fifo = argc > 3 && strcmp(argv[3], "fifo") == 0;
    if (seconds <= 0 || cycle_ns <= 0) {
        fprintf(stderr, "SECONDS and CYCLE_US must be positive\n");
        return 2;
    }
    if (fifo) {
        struct sched_param p = {.sched_priority = 80};
        if (sched_setscheduler(0, SCHED_FIFO, &p) != 0) {
            perror("SCHED_FIFO");
            return 1;
        }
    }
    long n = (long)(seconds * 1e9 / cycle_ns);
    long *late = malloc(sizeof(long) * (size_t)n);
    if (!late) return 1;
    struct timespec next, now;
    clock_gettime(CLOCK_MONOTONIC, &next);
    for (long i = 0; i < n; i++) {
        next.tv_nsec += cycle_ns;
        while (next.tv_nsec >= 1000000000L) {
            next.tv_nsec -= 1000000000L;
            next.tv_sec += 1;
        }
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL);
        clock_gettime(CLOCK_MONOTONIC, &now);
        late[i] = (now.tv_sec - next.tv_sec) * 1000000000L + (now.tv_nsec - next.tv_nsec);
    }
    qsort(late, (size_t)n, sizeof(long), cmp);
    printf("plain C clock_nanosleep%s: %ld cycles, late p50/p99/max %.1f/%.1f/%.1f us\n", fifo ? " SCHED_FIFO" : "", n,
           late[n / 2] / 1e3, late[(long)(n * 0.99)] / 1e3, late[n - 1] / 1e3);
    free(late);
    return 0;
}
