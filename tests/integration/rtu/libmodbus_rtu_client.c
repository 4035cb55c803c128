/* A libmodbus RTU master for tests/integration/rtu/test_rtu_libmodbus.py: an independent
 * implementation of the serial framing.  Usage: libmodbus_rtu_client DEVICE UNIT, then one
 * command a line on stdin:
 *   r TABLE ADDRESS COUNT   read (TABLE: c coils, d discrete inputs, i input, h holding)
 *   w TABLE ADDRESS VALUE   write one coil (c) or holding register (h)
 * Each answer is one line on stdout: "ok v1 v2 ..." or "error <libmodbus's message>". */
#include <errno.h>
#include <modbus.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: %s DEVICE UNIT\n", argv[0]);
        return 2;
    }
    modbus_t *ctx = modbus_new_rtu(argv[1], 19200, 'E', 8, 1);
    if (ctx == NULL || modbus_set_slave(ctx, atoi(argv[2])) != 0 || modbus_connect(ctx) != 0) {
        fprintf(stderr, "libmodbus: %s\n", modbus_strerror(errno));
        return 1;
    }
    modbus_set_response_timeout(ctx, 2, 0);
    char line[128], table;
    int address, n;
    uint16_t regs[MODBUS_MAX_READ_REGISTERS];
    uint8_t bits[MODBUS_MAX_READ_BITS];
    while (fgets(line, sizeof line, stdin) != NULL) {
        char op;
        if (sscanf(line, " %c %c %d %d", &op, &table, &address, &n) != 4) continue;
        int rc;
        if (op == 'r') {
            if (table == 'c') rc = modbus_read_bits(ctx, address, n, bits);
            else if (table == 'd') rc = modbus_read_input_bits(ctx, address, n, bits);
            else if (table == 'i') rc = modbus_read_input_registers(ctx, address, n, regs);
            else rc = modbus_read_registers(ctx, address, n, regs);
        } else {
            rc = table == 'c' ? modbus_write_bit(ctx, address, n)
                              : modbus_write_register(ctx, address, (uint16_t)n);
        }
        if (rc < 0) {
            printf("error %s\n", modbus_strerror(errno));
        } else {
            printf("ok");
            for (int i = 0; op == 'r' && i < rc; i++)
                printf(" %d", (table == 'c' || table == 'd') ? bits[i] : regs[i]);
            printf("\n");
        }
        fflush(stdout);
    }
    modbus_close(ctx);
    modbus_free(ctx);
    return 0;
}
