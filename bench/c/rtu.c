/* bench/modbus.py's RTU leg, both ends in libmodbus:
 *   rtu server DEVICE          a libmodbus RTU slave (unit 1, holding 0..2099) on DEVICE,
 *                              the baseline the gateway's RTU server is measured against;
 *                              prints "ready", serves until it is killed
 *   rtu load DEVICE SECONDS [WARM]
 *                              a libmodbus RTU master sending FC3 (holding 0..9, unit 1),
 *                              one request in flight, for WARM seconds unmeasured, then
 *                              SECONDS; prints the answers and the errors
 * 19,200 bit/s, 8E1 as the gateway's default; a pty pair (socat) carries the bytes at the
 * speed of the machine, so this measures the servers, not the line. */
#include <errno.h>
#include <modbus.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + t.tv_nsec / 1e9;
}

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: rtu server DEVICE | rtu load DEVICE SECONDS [WARM]\n");
        return 2;
    }
    modbus_t *ctx = modbus_new_rtu(argv[2], 19200, 'E', 8, 1);
    if (ctx == NULL || modbus_set_slave(ctx, 1) != 0 || modbus_connect(ctx) != 0) {
        fprintf(stderr, "libmodbus: %s\n", modbus_strerror(errno));
        return 1;
    }
    if (strcmp(argv[1], "server") == 0) {
        modbus_mapping_t *map = modbus_mapping_new(0, 0, 2100, 0);
        uint8_t query[MODBUS_RTU_MAX_ADU_LENGTH];
        printf("ready\n");
        fflush(stdout);
        for (;;) {
            int n = modbus_receive(ctx, query);
            if (n > 0) modbus_reply(ctx, query, n, map);
        }
    }
    double seconds = argc > 3 ? atof(argv[3]) : 2.0;
    double warm = argc > 4 ? atof(argv[4]) : 0.0;
    uint16_t regs[10];
    long answers = 0, errors = 0;
    modbus_set_response_timeout(ctx, 1, 0);
    for (double until = now() + warm; now() < until;)  /* unmeasured: caches, first scans */
        modbus_read_registers(ctx, 0, 10, regs);
    double end = now() + seconds;
    while (now() < end) {
        if (modbus_read_registers(ctx, 0, 10, regs) == 10) answers++;
        else errors++;
    }
    printf("%ld %ld\n", answers, errors);
    modbus_free(ctx);
    return 0;
}
