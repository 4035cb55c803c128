/* A libmodbus Modbus TCP server for bench/modbus.py: the C baseline the gateway is measured
 * against.  One thread, select() over the listening socket and every client, as libmodbus's
 * own multi-client example server does; holding registers 0..2099 (the gateway's holding map
 * spans the same addresses).  Prints its port, serves until stdin closes. */
#include <errno.h>
#include <modbus.h>
#include <netinet/in.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>

int main(void) {
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", 0);
    modbus_mapping_t *map = modbus_mapping_new(0, 0, 2100, 0);
    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
    if (ctx == NULL || map == NULL) {
        fprintf(stderr, "libmodbus: %s\n", modbus_strerror(errno));
        return 1;
    }
    int server = modbus_tcp_listen(ctx, 64);
    if (server < 0) {
        fprintf(stderr, "listen: %s\n", modbus_strerror(errno));
        return 1;
    }
    struct sockaddr_in address;
    socklen_t size = sizeof address;
    getsockname(server, (struct sockaddr *)&address, &size);
    printf("%d\n", ntohs(address.sin_port));
    fflush(stdout);

    fd_set all;
    FD_ZERO(&all);
    FD_SET(server, &all);
    FD_SET(STDIN_FILENO, &all);
    int highest = server;
    for (;;) {
        fd_set ready = all;
        if (select(highest + 1, &ready, NULL, NULL, NULL) < 0) {
            if (errno == EINTR) continue;
            perror("select");
            return 1;
        }
        for (int fd = 0; fd <= highest; fd++) {
            if (!FD_ISSET(fd, &ready)) continue;
            if (fd == STDIN_FILENO) {  /* the bench closed our stdin: done */
                char c;
                if (read(STDIN_FILENO, &c, 1) <= 0) {
                    modbus_mapping_free(map);
                    modbus_free(ctx);
                    return 0;
                }
            } else if (fd == server) {
                int client = accept(server, NULL, NULL);
                if (client >= 0) {
                    FD_SET(client, &all);
                    if (client > highest) highest = client;
                }
            } else {
                modbus_set_socket(ctx, fd);
                int n = modbus_receive(ctx, query);
                if (n > 0) {
                    modbus_reply(ctx, query, n, map);
                } else if (n == -1) {  /* the client closed, or sent garbage */
                    close(fd);
                    FD_CLR(fd, &all);
                }
            }
        }
    }
}
