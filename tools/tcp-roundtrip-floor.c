/* The floor of a Modbus TCP exchange on this computer: two processes on loopback TCP (Nagle off,
 * as tokio-modbus and pkm-plc's station set it), the client sending a request of REQUEST bytes
 * every PERIOD_US and waiting for an answer of ANSWER bytes, the server answering at once. It
 * prints the round trip's mean, p50, p99 and max in µs: two wake-ups of blocked threads and four
 * passes through the loopback stack, nothing else. Run it beside `pkm-plc run --bus tcp:…` and
 * `pkm-plc io-sim --tcp …` in the same minute: what both show is the machine's, what pkm-plc adds
 * is the rest. A `tables` exchange is four transactions, an `image` exchange one.
 *
 *   cc -O2 -o target/tcp-roundtrip-floor tools/tcp-roundtrip-floor.c
 *   target/tcp-roundtrip-floor SECONDS [PERIOD_US] [REQUEST] [ANSWER]
 *
 * Defaults: every 5000 µs (the Modbus link's period), a 12-byte request (a read request with its
 * MBAP header) and a 33-byte answer: Modbus-sized frames, whose length barely matters here.
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

static int cmp(const void *a, const void *b) {
    long x = *(const long *)a, y = *(const long *)b;
    return (x > y) - (x < y);
}

/* Reads exactly n bytes; 0 on success, -1 when the peer closed or an error came. */
static int read_all(int fd, char *buf, size_t n) {
    while (n > 0) {
        ssize_t got = read(fd, buf, n);
        if (got <= 0) return -1;
        buf += got;
        n -= (size_t)got;
    }
    return 0;
}

static long now_ns(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec * 1000000000L + t.tv_nsec;
}

static void no_delay(int fd) {
    int one = 1;
    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: %s SECONDS [PERIOD_US] [REQUEST] [ANSWER]\n", argv[0]);
        return 2;
    }
    double seconds = atof(argv[1]);
    long period_ns = (argc > 2 ? atol(argv[2]) : 5000) * 1000L;
    long request = argc > 3 ? atol(argv[3]) : 12;
    long answer = argc > 4 ? atol(argv[4]) : 33;
    if (seconds <= 0 || period_ns <= 0 || request <= 0 || answer <= 0 || request > 4096 || answer > 4096) {
        fprintf(stderr, "SECONDS and PERIOD_US must be positive, REQUEST and ANSWER 1..4096 bytes\n");
        return 2;
    }
    int listener = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in addr = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t len = sizeof addr;
    if (listener < 0 || bind(listener, (struct sockaddr *)&addr, sizeof addr) != 0 || listen(listener, 1) != 0 ||
        getsockname(listener, (struct sockaddr *)&addr, &len) != 0) {
        perror("loopback listener");
        return 1;
    }
    char buf[4096];
    memset(buf, 0x5a, sizeof buf);
    pid_t server = fork();
    if (server < 0) {
        perror("fork");
        return 1;
    }
    if (server == 0) {
        /* The server: answer every request at once, until the client closes. */
        int fd = accept(listener, NULL, NULL);
        if (fd < 0) _exit(1);
        no_delay(fd);
        while (read_all(fd, buf, (size_t)request) == 0) {
            if (write(fd, buf, (size_t)answer) != answer) break;
        }
        _exit(0);
    }
    close(listener);
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    if (fd < 0 || connect(fd, (struct sockaddr *)&addr, sizeof addr) != 0) {
        perror("connect");
        kill(server, SIGKILL);
        return 1;
    }
    no_delay(fd);
    long n = (long)(seconds * 1e9 / period_ns);
    long *trip = malloc(sizeof(long) * (size_t)(n > 0 ? n : 1));
    if (!trip || n <= 0) return 1;
    long next = now_ns();
    double sum = 0;
    for (long i = 0; i < n; i++) {
        next += period_ns;
        struct timespec at = {.tv_sec = next / 1000000000L, .tv_nsec = next % 1000000000L};
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &at, NULL);
        long start = now_ns();
        if (write(fd, buf, (size_t)request) != request || read_all(fd, buf, (size_t)answer) != 0) {
            fprintf(stderr, "the loopback server stopped answering\n");
            kill(server, SIGKILL);
            return 1;
        }
        trip[i] = now_ns() - start;
        sum += (double)trip[i];
    }
    close(fd);
    waitpid(server, NULL, 0);
    qsort(trip, (size_t)n, sizeof(long), cmp);
    printf("plain C loopback TCP round trip (%ld-byte request, %ld-byte answer, every %ld us): %ld trips, "
           "mean/p50/p99/max %.1f/%.1f/%.1f/%.1f us\n",
           request, answer, period_ns / 1000, n, sum / (double)n / 1e3, trip[n / 2] / 1e3,
           trip[(long)(n * 0.99)] / 1e3, trip[n - 1] / 1e3);
    free(trip);
    return 0;
}
