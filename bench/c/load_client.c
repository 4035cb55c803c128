/* The load client of bench/modbus.py: N connections, each with one FC3 request in flight at a
 * time (N independent pollers), driven by one thread with poll(), so that the client costs
 * little of the machine and the same client measures every server.
 *   load_client PORT CONNECTIONS SECONDS  ->  prints the answers received */
#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + t.tv_nsec / 1e9;
}

int main(int argc, char **argv) {
    if (argc != 4) {
        fprintf(stderr, "usage: load_client PORT CONNECTIONS SECONDS\n");
        return 2;
    }
    int port = atoi(argv[1]), n = atoi(argv[2]);
    double seconds = atof(argv[3]);
    /* FC3, unit 1, holding 0..9: the answer is 7 + 2 + 20 = 29 bytes */
    unsigned char request[12] = {0, 0, 0, 0, 0, 6, 1, 3, 0, 0, 0, 10};
    enum { ANSWER = 29 };
    struct pollfd *fds = calloc(n, sizeof *fds);
    int *got = calloc(n, sizeof *got);
    unsigned char (*answer)[ANSWER] = calloc(n, ANSWER);
    struct sockaddr_in to = {.sin_family = AF_INET, .sin_port = htons(port)};
    inet_pton(AF_INET, "127.0.0.1", &to.sin_addr);
    for (int i = 0; i < n; i++) {
        int s = socket(AF_INET, SOCK_STREAM, 0), one = 1;
        setsockopt(s, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        if (connect(s, (struct sockaddr *)&to, sizeof to) < 0) {
            perror("connect");
            return 1;
        }
        fds[i].fd = s;
        fds[i].events = POLLIN;
    }
    long done = 0;
    double end = now() + seconds;
    for (int i = 0; i < n; i++) write(fds[i].fd, request, sizeof request);
    while (now() < end) {
        if (poll(fds, n, 1000) < 0) {
            perror("poll");
            return 1;
        }
        for (int i = 0; i < n; i++) {
            if (!(fds[i].revents & POLLIN)) continue;
            /* one request in flight: read no further than its answer */
            ssize_t r = read(fds[i].fd, answer[i] + got[i], ANSWER - got[i]);
            if (r <= 0) {
                fprintf(stderr, "connection %d closed\n", i);
                return 1;
            }
            got[i] += r;
            if (got[i] >= 8 && answer[i][7] != 3) {  /* an exception: not what we measure */
                fprintf(stderr, "connection %d: answer with function code %d\n", i,
                        answer[i][7]);
                return 1;
            }
            if (got[i] == ANSWER) {  /* a whole answer: count it, ask again */
                got[i] = 0;
                done++;
                write(fds[i].fd, request, sizeof request);
            }
        }
    }
    printf("%ld\n", done);
    return 0;
}
