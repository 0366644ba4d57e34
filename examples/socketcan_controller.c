/*
 * socketcan_controller.c: an outside controller for the bench's virtual ODrives, in C against
 * Linux SocketCAN only (no library, nothing of the bench). It is what a robot computer's drive
 * node does with two ODrives speaking CANSimple (firmware 0.6):
 *
 *   1. for each drive (nodes 0 and 1 by default): Clear_Errors, Set_Controller_Mode
 *      TORQUE_CONTROL / PASSTHROUGH, Set_Input_Torque 0, then Set_Axis_State
 *      CLOSED_LOOP_CONTROL (8);
 *   2. a speed loop per wheel: the torque tau = clamp(GAIN (vel_ref - vel), +-TAU_MAX) from the
 *      drive's own Vel_Estimate (its cyclic Get_Encoder_Estimates frame), sent either once per
 *      encoder frame of that drive (default) or at a fixed rate of its own (-f HZ);
 *   3. with -a, a drive whose heartbeat says it is not in closed loop (it tripped, or a new
 *      bench run's drives came up) is armed again as in 1., at most every 0.5 s: a device kept
 *      running through `hil campaign`'s runs;
 *   4. on SIGINT / SIGTERM (or after -d seconds): torque 0, Set_Axis_State IDLE, a summary line.
 *
 * Build (a static binary runs unchanged in a chroot or a minimal guest):
 *
 *     gcc -O2 -static -Wall -Wextra -o socketcan_controller examples/socketcan_controller.c
 *
 * Run it against the bench's virtual drives on a SocketCAN bus (vcan0 here; docs/external.md):
 *
 *     hil run --controller external --cmd-path can --can-interface socketcan \
 *         --can-channel vcan0 --duration 10 --out runs/c-device &
 *     ./socketcan_controller -i vcan0 -l 0 -r 1
 *     hil report runs/c-device
 *
 * Options: -i IFNAME (vcan0), -l NODE (left, 0), -r NODE (right, 1), -v VEL_REF (motor rev/s,
 * 5), -f HZ (0: one torque per encoder frame), -d SECONDS (0: until a signal), -a (re-arm).
 * Exit code 0 after a clean stop; 2 for bad options; 1 when the bus cannot be opened or written.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <linux/can.h>
#include <math.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

/* CANSimple 0.6: arbitration id = node << 5 | cmd (11 bits). */
enum {
    CMD_HEARTBEAT = 0x01,
    CMD_SET_AXIS_STATE = 0x07,
    CMD_GET_ENCODER_ESTIMATES = 0x09,
    CMD_SET_CONTROLLER_MODE = 0x0B,
    CMD_SET_INPUT_TORQUE = 0x0E,
    CMD_CLEAR_ERRORS = 0x18,
};
enum { AXIS_IDLE = 1, AXIS_CLOSED_LOOP = 8 };
enum { CONTROL_TORQUE = 1, INPUT_PASSTHROUGH = 1 };

/* N m per motor rev/s of speed error: with the default robot's 7.9e-4 N m per rev/s^2 seen by
 * a motor (docs/can.md) a time constant of 0.16 s, stable down to a 10 Hz loop. */
#define GAIN 0.005f
#define TAU_MAX 0.1f /* N m: well inside the drives' torque limit (0.40 N m by default) */

static volatile sig_atomic_t stop_requested;

struct wheel {
    int node;
    float vel;              /* newest Vel_Estimate, motor rev/s */
    unsigned long estimates; /* encoder frames read */
    unsigned long torques;   /* torque frames sent */
    int axis_state;          /* from the newest heartbeat, -1 before one */
    double armed_at;         /* CLOCK_MONOTONIC s of the last arming */
    unsigned long rearms;    /* armed again after a heartbeat said idle (-a) */
};

static struct {
    int fd;
    unsigned long write_errors;
    unsigned long other_frames;
} bus;

static void on_signal(int sig) {
    (void)sig;
    stop_requested = 1;
}

static double now_s(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

static void put_u32(uint8_t *p, uint32_t v) {
    for (int i = 0; i < 4; i++) p[i] = (uint8_t)(v >> (8 * i)); /* little endian on the wire */
}

static void put_f32(uint8_t *p, float f) {
    uint32_t v;
    memcpy(&v, &f, sizeof v);
    put_u32(p, v);
}

static float get_f32(const uint8_t *p) {
    uint32_t v = (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
    float f;
    memcpy(&f, &v, sizeof f);
    return f;
}

/* One frame; a full queue (ENOBUFS) is counted and the frame dropped, as a drive node would. */
static int send_frame(int node, int cmd, const uint8_t *data, int len) {
    struct can_frame fr;
    memset(&fr, 0, sizeof fr);
    fr.can_id = (canid_t)(node << 5 | cmd);
    fr.can_dlc = (uint8_t)len;
    if (len) memcpy(fr.data, data, (size_t)len);
    if (write(bus.fd, &fr, sizeof fr) != (ssize_t)sizeof fr) {
        if (errno == ENOBUFS || errno == EAGAIN || errno == EINTR) {
            bus.write_errors++;
            return 0;
        }
        perror("write");
        return -1;
    }
    return 0;
}

static int send_u32(int node, int cmd, uint32_t v) {
    uint8_t d[4];
    put_u32(d, v);
    return send_frame(node, cmd, d, 4);
}

static int send_torque(struct wheel *w, float tau) {
    uint8_t d[4];
    put_f32(d, tau);
    if (send_frame(w->node, CMD_SET_INPUT_TORQUE, d, 4) < 0) return -1;
    w->torques++;
    return 0;
}

static int arm(const struct wheel *w) {
    uint8_t mode[8], identify = 0;
    put_u32(mode, CONTROL_TORQUE);
    put_u32(mode + 4, INPUT_PASSTHROUGH);
    uint8_t zero[4];
    put_f32(zero, 0.0f);
    if (send_frame(w->node, CMD_CLEAR_ERRORS, &identify, 1) < 0) return -1;
    if (send_frame(w->node, CMD_SET_CONTROLLER_MODE, mode, 8) < 0) return -1;
    if (send_frame(w->node, CMD_SET_INPUT_TORQUE, zero, 4) < 0) return -1;
    return send_u32(w->node, CMD_SET_AXIS_STATE, AXIS_CLOSED_LOOP);
}

static float law(const struct wheel *w, float vel_ref) {
    float tau = GAIN * (vel_ref - w->vel);
    if (tau > TAU_MAX) tau = TAU_MAX;
    if (tau < -TAU_MAX) tau = -TAU_MAX;
    return tau;
}

static int open_bus(const char *ifname) {
    int fd = socket(PF_CAN, SOCK_RAW, CAN_RAW);
    if (fd < 0) {
        perror("socket(PF_CAN, SOCK_RAW, CAN_RAW)");
        return -1;
    }
    struct ifreq ifr;
    memset(&ifr, 0, sizeof ifr);
    snprintf(ifr.ifr_name, sizeof ifr.ifr_name, "%s", ifname);
    if (ioctl(fd, SIOCGIFINDEX, &ifr) < 0) {
        fprintf(stderr, "no CAN interface %s: %s\n", ifname, strerror(errno));
        close(fd);
        return -1;
    }
    struct sockaddr_can addr;
    memset(&addr, 0, sizeof addr);
    addr.can_family = AF_CAN;
    addr.can_ifindex = ifr.ifr_ifindex;
    if (bind(fd, (struct sockaddr *)&addr, sizeof addr) < 0) {
        perror("bind");
        close(fd);
        return -1;
    }
    return fd;
}

static void usage(const char *argv0) {
    fprintf(stderr,
            "usage: %s [-i IFNAME] [-l NODE] [-r NODE] [-v VEL_REF] [-f HZ] [-d S] [-a]\n",
            argv0);
}

int main(int argc, char **argv) {
    const char *ifname = "vcan0";
    int node_left = 0, node_right = 1;
    double hz = 0.0, duration = 0.0;
    float vel_ref = 5.0f;
    int opt, rearm = 0;
    char *end;
    while ((opt = getopt(argc, argv, "i:l:r:v:f:d:ah")) != -1) {
        errno = 0;
        end = optarg ? optarg + strlen(optarg) : NULL;
        switch (opt) {
        case 'i': ifname = optarg; break;
        case 'l': node_left = (int)strtol(optarg, &end, 10); break;
        case 'r': node_right = (int)strtol(optarg, &end, 10); break;
        case 'v': vel_ref = strtof(optarg, &end); break;
        case 'f': hz = strtod(optarg, &end); break;
        case 'd': duration = strtod(optarg, &end); break;
        case 'a': rearm = 1; continue;
        default: usage(argv[0]); return 2;
        }
        if (errno || *end || (opt != 'i' && end == optarg)) {
            usage(argv[0]);
            return 2;
        }
    }
    if (node_left < 0 || node_left > 62 || node_right < 0 || node_right > 62 ||
        node_left == node_right || hz < 0 || duration < 0) {
        usage(argv[0]);
        return 2;
    }

    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal; /* no SA_RESTART: poll() returns EINTR and the loop ends */
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);

    bus.fd = open_bus(ifname);
    if (bus.fd < 0) return 1;
    struct wheel wheels[2] = {{node_left, 0, 0, 0, -1, 0, 0}, {node_right, 0, 0, 0, -1, 0, 0}};
    for (int i = 0; i < 2; i++) {
        if (arm(&wheels[i]) < 0) return 1;
        wheels[i].armed_at = now_s();
    }
    printf("armed nodes %d and %d on %s (torque control, %s)\n", node_left, node_right, ifname,
           hz > 0 ? "own rate" : "one torque per encoder frame");
    fflush(stdout);

    const double t0 = now_s();
    const double period = hz > 0 ? 1.0 / hz : 0.0;
    double next_tick = t0 + period;
    int rc = 0;
    while (!stop_requested && rc == 0) {
        double t = now_s();
        if (duration > 0 && t - t0 >= duration) break;
        if (period > 0 && t >= next_tick) {
            for (int i = 0; i < 2 && rc == 0; i++) rc = send_torque(&wheels[i], law(&wheels[i], vel_ref));
            next_tick += period;
            if (next_tick < t) next_tick = t + period; /* a missed slot is skipped, not burst */
            continue;
        }
        int timeout_ms = period > 0 ? (int)((next_tick - t) * 1e3) : 100;
        struct pollfd pfd = {bus.fd, POLLIN, 0};
        int n = poll(&pfd, 1, timeout_ms < 0 ? 0 : timeout_ms);
        if (n < 0) {
            if (errno == EINTR) continue;
            perror("poll");
            rc = -1;
            break;
        }
        if (n == 0) continue;
        struct can_frame fr;
        ssize_t got = read(bus.fd, &fr, sizeof fr);
        if (got != (ssize_t)sizeof fr) continue;
        if (fr.can_id & (CAN_EFF_FLAG | CAN_RTR_FLAG | CAN_ERR_FLAG)) {
            bus.other_frames++;
            continue;
        }
        int node = (int)(fr.can_id >> 5), cmd = (int)(fr.can_id & 0x1F);
        struct wheel *w = node == node_left ? &wheels[0] : node == node_right ? &wheels[1] : NULL;
        if (w && cmd == CMD_GET_ENCODER_ESTIMATES && fr.can_dlc == 8 &&
            isfinite(get_f32(fr.data + 4))) {
            /* a non-finite estimate is another node's garbage, never a drive's: skipped, so
             * that no NaN torque is ever computed from it */
            w->vel = get_f32(fr.data + 4);
            w->estimates++;
            if (period == 0) rc = send_torque(w, law(w, vel_ref));
        } else if (w && cmd == CMD_HEARTBEAT && fr.can_dlc >= 5) {
            w->axis_state = fr.data[4];
            if (rearm && w->axis_state != AXIS_CLOSED_LOOP && t - w->armed_at >= 0.5) {
                rc = arm(w);
                w->armed_at = t;
                w->rearms++;
            }
        } else {
            bus.other_frames++;
        }
    }

    uint8_t zero[4];
    put_f32(zero, 0.0f);
    for (int i = 0; i < 2; i++) {
        send_frame(wheels[i].node, CMD_SET_INPUT_TORQUE, zero, 4);
        send_u32(wheels[i].node, CMD_SET_AXIS_STATE, AXIS_IDLE);
    }
    close(bus.fd);
    printf("stopped after %.2f s: node %d: %lu estimates, %lu torques, axis state %d; "
           "node %d: %lu estimates, %lu torques, axis state %d; %lu other frames, "
           "%lu frames dropped by a full queue, %lu re-arms\n",
           now_s() - t0, wheels[0].node, wheels[0].estimates, wheels[0].torques,
           wheels[0].axis_state, wheels[1].node, wheels[1].estimates, wheels[1].torques,
           wheels[1].axis_state, bus.other_frames, bus.write_errors,
           wheels[0].rearms + wheels[1].rearms);
    return rc == 0 ? 0 : 1;
}
