/* How late this machine wakes an idle SCHED_FIFO thread: the floor under every wall-clock figure.
 *
 * One thread at SCHED_FIFO 80 (memory locked) sleeps to absolute deadlines 1 ms apart, N times,
 * and prints the lateness percentiles and how many wake-ups came more than a period late. Nothing
 * of this project runs in it, so what it shows is the kernel's and the hypervisor's, not the
 * loop's: on a VM whose p99.9 is milliseconds, a 1 kHz loop and the simulated bench's threads
 * overrun whatever the code does (docs/realtime.md, Timing).
 *
 *   cc -O2 -o /tmp/wake_latency bench/wake_latency.c && /tmp/wake_latency 10000
 *
 * Without CAP_SYS_NICE it says so and measures at the normal policy.
 */
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/mman.h>
#include <time.h>

#define PERIOD_NS 1000000L

static int by_value(const void *a, const void *b) {
    long x = *(const long *)a, y = *(const long *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv) {
    int n = argc > 1 ? atoi(argv[1]) : 10000;
    if (n < 1000) {
        fprintf(stderr, "usage: %s [wake-ups >= 1000]\n", argv[0]);
        return 2;
    }
    struct sched_param fifo = {.sched_priority = 80};
    if (sched_setscheduler(0, SCHED_FIFO, &fifo) != 0)
        perror("SCHED_FIFO refused; measuring at the normal policy");
    mlockall(MCL_CURRENT | MCL_FUTURE);
    long *late = malloc(sizeof(long) * n);
    if (late == NULL)
        return 1;
    struct timespec deadline, now;
    clock_gettime(CLOCK_MONOTONIC, &deadline);
    for (int i = 0; i < n; i++) {
        deadline.tv_nsec += PERIOD_NS;
        if (deadline.tv_nsec >= 1000000000L) {
            deadline.tv_nsec -= 1000000000L;
            deadline.tv_sec++;
        }
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &deadline, NULL);
        clock_gettime(CLOCK_MONOTONIC, &now);
        late[i] = (now.tv_sec - deadline.tv_sec) * 1000000000L + (now.tv_nsec - deadline.tv_nsec);
    }
    qsort(late, n, sizeof(long), by_value);
    int over = 0;
    for (int i = 0; i < n; i++)
        over += late[i] > PERIOD_NS;
    printf("%d wake-ups 1 ms apart: late p50 %ld us, p99 %ld us, p99.9 %ld us, max %ld us; "
           "more than a period late: %d\n",
           n, late[n / 2] / 1000, late[n * 99 / 100] / 1000, late[n * 999 / 1000] / 1000, late[n - 1] / 1000, over);
    free(late);
    return 0;
}
