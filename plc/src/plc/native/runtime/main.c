/*
 * main.c - options, start-up and orderly shutdown of the soft-PLC runtime.
 *
 * Start-up: check the program against the ABI, init() it, bind its located
 * variables to the image, open the I/O layer, restore retained data, publish
 * the first image, start the Modbus server, then run the scan loop on this
 * thread (pinned to one CPU with --cpu, SCHED_FIFO when permitted).
 *
 * SIGINT/SIGTERM are blocked in every thread and polled by the scan loop; on
 * either the program stops, outputs go safe (all coils cleared in the image,
 * coils and words at zero at the I/O layer), retained data are flushed, the server
 * closes its connections and the process exits 0.
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <getopt.h>
#include <inttypes.h>
#include <sched.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "runtime.h"
#include "monitor.h"

#define DEFAULT_PORT 5020
#define DEFAULT_MAX_CLIENTS 32
#define DEFAULT_WRITABLE_COILS "400-799"
#define DEFAULT_WRITABLE_REGISTERS "512-8191"
#define DEFAULT_RETAIN_INTERVAL_MS 200
#define DEFAULT_RT_PRIORITY 50
#define FALLBACK_TICK_NS 10000000u
#define DEFAULT_WATCHDOG_MS 1000
#define DEFAULT_FRAME_TIMEOUT_MS 2000
#define DEFAULT_TLS_PORT 802              /* Modbus/TCP Security's registered port */

static void usage(FILE *f)
{
    fprintf(f,
"usage: " RT_NAME " [options]\n"
"Runs the linked PLC program as a soft-PLC serving Modbus/TCP (OpenPLC address map).\n"
"\n"
"  --bind ADDR              IPv4 address to listen on (default 127.0.0.1)\n"
"  --port N                 TCP port (default %d; 0 = any free port, logged)\n"
"  --io sim|none|modbus     I/O layer (default sim: outputs looped back to inputs;\n"
"                           modbus: remote I/O devices given by --io-device)\n"
"  --sim-flag %%IXa.b        with --io sim: hold this discrete input TRUE, the program's\n"
"                           sign that its plant models stand in for the machine (default: none)\n"
"  --io-device SPEC         a remote I/O device of --io modbus (repeatable, at most %u;\n"
"                           `plc run` writes SPEC from the run configuration, see io_modbus.c)\n"
"  --retain FILE            file that keeps RETAIN data across restarts (default: none)\n"
"  --retain-interval MS     minimum time between two retain saves (default %d)\n"
"  --retain-registers LIST  holding registers saved with RETAIN data, e.g. 1024-1039\n"
"  --allow ADDR[/BITS][=ROLE]  accept clients only from these addresses (repeatable);\n"
"                           ROLE is what they may write: read (nothing: exception 01),\n"
"                           host (the host ranges below) or engineer (every writable\n"
"                           coil and register; the default).  The longest prefix that\n"
"                           holds the client's address decides; no --allow: any\n"
"                           client, engineer\n"
"  --max-clients N          concurrent client limit (default %d)\n"
"  --frame-timeout MS       drop a client whose request is still incomplete, or whose\n"
"                           responses stay unread, after MS (default %d)\n"
"  --read-only              answer every write function code with exception 01\n"
"  --writable-coils LIST    coils a client of role engineer may write\n"
"                           (default " DEFAULT_WRITABLE_COILS ", 'none')\n"
"  --writable-registers LIST  holding registers an engineer may write\n"
"                           (default " DEFAULT_WRITABLE_REGISTERS ", 'none')\n"
"  --host-coils LIST        of the writable coils, those a client of role host may write\n"
"                           (default: every writable coil)\n"
"  --host-registers LIST    of the writable registers, those a host may write (same default)\n"
"  --tls-cert FILE          serve Modbus/TCP Security (MBAPS: TLS 1.2 or later) beside the\n"
"                           plain listener, with this server certificate (PEM); needs\n"
"                           --tls-key and --tls-ca.  A client must present a certificate\n"
"                           signed by the CA, else the handshake is refused; its role is\n"
"                           the certificate's role extension (OID 1.3.6.1.4.1.50316.802.1,\n"
"                           a UTF8String read, host or engineer); a certificate without a\n"
"                           known role is refused.  --allow does not apply to TLS clients\n"
"  --tls-key FILE           the server certificate's private key (PEM)\n"
"  --tls-ca FILE            the CA certificate(s) that sign the clients' certificates (PEM)\n"
"  --tls-bind ADDR          IPv4 address of the TLS listener (default: --bind)\n"
"  --tls-port N             its TCP port (default %d; 0 = any free port, logged).  TLS\n"
"                           clients share --max-clients; a handshake not done within\n"
"                           --frame-timeout is dropped\n"
"  --no-rt                  do not ask for SCHED_FIFO\n"
"  --rt-priority N          SCHED_FIFO priority of the scan thread, 1..98 (default %d;\n"
"                           the watchdog runs 1 level above it, the remote I/O threads\n"
"                           5 and the Modbus server thread 10 levels below)\n"
"  --cpu N                  pin the scan thread (only it) to CPU N, an online CPU\n"
"                           (default: not pinned; keep other work off N, e.g. isolcpus=)\n"
"  --cpu-latency US         while running, keep every CPU out of idle states that take\n"
"                           longer than US microseconds to wake (PM QoS, /dev/cpu_dma_latency;\n"
"                           0: idle CPUs poll: lowest wake-up jitter, most power; default: none)\n"
"  --status auto|tty|log|off  live status line (auto: on a terminal, else log lines)\n"
"  --status-interval S      seconds between status log lines when not on a terminal (default 10)\n"
"  --duration S             stop after S seconds (benchmarks; default: run until SIGINT/SIGTERM)\n"
"  --watchdog MS            longest run() call before outputs are forced safe (default %d, 0 = off)\n"
"  --monitor PATH           serve the monitoring channel (watch, write, force) on this\n"
"                           Unix socket, mode 0600 (default: none)\n"
"  --monitor-token FILE     the token that unlocks writes and forces (without: read-only)\n"
"  --audit FILE             append every monitor write, force and refused token, and every\n"
"                           Modbus write request (served or refused, at most %u lines a\n"
"                           second, the rest summed up) here\n"
"  --events FILE            the description the application's events read (the signals\n"
"                           they watch; written by plc run); without an application: ignored\n"
"  --describe-retain        print the retained entries (path, type, location, bytes) and the\n"
"                           located variables, one per line, tab-separated, and exit\n"
"  --version, --help\n"
"\n"
"Under systemd (Type=notify) the runtime sends READY=1 after its first scan and\n"
"WATCHDOG=1 while its scans run ($NOTIFY_SOCKET, $WATCHDOG_USEC); log lines carry\n"
"journald priorities when stderr is the journal ($JOURNAL_STREAM).\n"
"\n"
"Diagnostics are in input registers %u-%u (see runtime.h).  Exit status: 0 after\n"
"SIGINT/SIGTERM or --duration, 1 when start-up fails, 2 on a usage error or when\n"
"the Modbus address cannot be bound (e.g. the port is in use; nothing is written then).\n",
            DEFAULT_PORT, IO_MAX_DEVICES, DEFAULT_RETAIN_INTERVAL_MS, DEFAULT_MAX_CLIENTS, DEFAULT_FRAME_TIMEOUT_MS,
            DEFAULT_TLS_PORT, DEFAULT_RT_PRIORITY,
            DEFAULT_WATCHDOG_MS, MODBUS_AUDIT_PER_S, DIAG_BASE, DIAG_BASE + DIAG_COUNT - 1);
}

static int usage_error(const char *fmt, const char *arg)
{
    fprintf(stderr, RT_NAME ": error: ");
    fprintf(stderr, fmt, arg);
    fprintf(stderr, "\n(try --help)\n");
    return 2;
}

static bool parse_long(const char *s, long lo, long hi, long *out)
{
    char *end;
    errno = 0;
    long v = strtol(s, &end, 10);
    if (errno || end == s || *end || v < lo || v > hi)
        return false;
    *out = v;
    return true;
}

static bool parse_double(const char *s, double lo, double *out)
{
    char *end;
    errno = 0;
    double v = strtod(s, &end);
    if (errno || end == s || *end || !(v >= lo))
        return false;
    *out = v;
    return true;
}

/* text into dst (of size bytes) when it is a dotted IPv4 address that fits */
static bool copy_ipv4(char *dst, size_t size, const char *text)
{
    struct in_addr ia;
    if (strlen(text) >= size || inet_pton(AF_INET, text, &ia) != 1)
        return false;
    snprintf(dst, size, "%s", text);
    return true;
}

const char *role_name(client_role_t role)
{
    return role == ROLE_READ ? "read" : role == ROLE_HOST ? "host" : "engineer";
}

/* One --allow list: ADDR[/BITS][=ROLE] entries, comma-separated.  0, or -1 with the reason in err. */
static int add_allow(rt_options_t *o, const char *text, char *err, size_t err_size)
{
    char buf[64];
    const char *p = text;

    while (*p) {
        size_t n = strcspn(p, ",");
        if (n == 0 || n >= sizeof buf) {
            snprintf(err, err_size, "an empty or over-long entry in '%s'", text);
            return -1;
        }
        memcpy(buf, p, n);
        buf[n] = 0;
        p += n + (p[n] == ',');

        client_role_t role = ROLE_ENGINEER;
        char *eq = strchr(buf, '=');
        if (eq) {
            *eq = 0;
            if (strcmp(eq + 1, "read") == 0)
                role = ROLE_READ;
            else if (strcmp(eq + 1, "host") == 0)
                role = ROLE_HOST;
            else if (strcmp(eq + 1, "engineer") != 0) {
                snprintf(err, err_size, "'%s' is not a role (read, host or engineer)", eq + 1);
                return -1;
            }
        }
        long bits = 32;
        char *slash = strchr(buf, '/');
        if (slash) {
            *slash = 0;
            if (!parse_long(slash + 1, 0, 32, &bits)) {
                snprintf(err, err_size, "'%s' is not a prefix length 0..32", slash + 1);
                return -1;
            }
        }
        struct in_addr ia;
        if (inet_pton(AF_INET, buf, &ia) != 1) {
            snprintf(err, err_size, "'%s' is not an IPv4 address", buf);
            return -1;
        }
        if (o->n_allow >= RT_MAX_ALLOW) {
            snprintf(err, err_size, "more than %d networks", RT_MAX_ALLOW);
            return -1;
        }
        uint32_t mask = bits == 0 ? 0 : 0xffffffffu << (32 - bits);
        o->allow[o->n_allow].mask = mask;
        o->allow[o->n_allow].addr = ntohl(ia.s_addr) & mask;
        o->allow[o->n_allow].role = role;
        for (int i = 0; i < o->n_allow; i++)     /* one network, two roles: which one would be meant? */
            if (o->allow[i].addr == o->allow[o->n_allow].addr && o->allow[i].mask == mask
                && o->allow[i].role != role) {
                snprintf(err, err_size, "%s/%ld is given two roles (%s and %s)", buf, bits,
                         role_name(o->allow[i].role), role_name(role));
                return -1;
            }
        o->n_allow++;
    }
    return 0;
}

static int parse_set(addr_set_t *s, const char *text, unsigned limit, const char *what)
{
    char err[160];

    memset(s, 0, sizeof *s);
    if (strcmp(text, "none") == 0)
        return 0;
    if (addr_set_parse(s, text, limit, err, sizeof err) != 0) {
        fprintf(stderr, RT_NAME ": error: %s: %s\n", what, err);
        return 2;
    }
    return 0;
}

/*
 * --cpu N: N must be an online CPU of this machine (below the count of online
 * CPUs; one taken offline later makes the pinning fail, logged at run time).
 * The process's own affinity
 * mask is not the bound: a thread may be pinned outside it (a bench or a
 * systemd CPUAffinity= keeps everything else off N and gives N to the scan).
 */
static int parse_cpu(const char *text, int *out)
{
    long online = sysconf(_SC_NPROCESSORS_ONLN);
    long v;

    if (!parse_long(text, 0, CPU_SETSIZE - 1, &v))
        return usage_error("--cpu: '%s' is not a CPU number", text);
    if (online < 1)
        online = 1;
    if (v >= online) {
        char range[32];
        snprintf(range, sizeof range, "%s%ld", online > 1 ? "0.." : "", online - 1);
        fprintf(stderr, RT_NAME ": error: --cpu: CPU %ld is not online (online CPUs: %s)\n(try --help)\n", v,
                range);
        return 2;
    }
    *out = (int)v;
    return 0;
}

/* --sim-flag %IXa.b: a discrete input of OpenPLC's map, %IX0.0..%IX99.7. */
static int parse_discrete_input(const char *text, int *out)
{
    unsigned byte, bit;
    char tail;

    if (sscanf(text, "%%IX%u.%u%c", &byte, &bit, &tail) != 2 || byte >= MAP_BITS / 8 || bit > 7)
        return usage_error("--sim-flag: '%s' is not a discrete input %%IX0.0..%%IX99.7", text);
    *out = (int)(8 * byte + bit);
    return 0;
}

enum { OPT_BIND = 256, OPT_PORT, OPT_IO, OPT_IO_DEVICE, OPT_RETAIN, OPT_RETAIN_INTERVAL, OPT_RETAIN_REGISTERS, OPT_ALLOW,
       OPT_MAX_CLIENTS, OPT_FRAME_TIMEOUT, OPT_READ_ONLY, OPT_WRITABLE_COILS, OPT_WRITABLE_REGISTERS, OPT_NO_RT, OPT_RT_PRIORITY, OPT_CPU, OPT_CPU_LATENCY, OPT_STATUS,
       OPT_STATUS_INTERVAL, OPT_DURATION, OPT_WATCHDOG, OPT_DESCRIBE_RETAIN, OPT_VERSION, OPT_HELP,
       OPT_MONITOR, OPT_MONITOR_TOKEN, OPT_AUDIT, OPT_EVENTS, OPT_SIM_FLAG, OPT_HOST_COILS, OPT_HOST_REGISTERS,
       OPT_TLS_CERT, OPT_TLS_KEY, OPT_TLS_CA, OPT_TLS_BIND, OPT_TLS_PORT };

static int parse_options(int argc, char **argv, rt_options_t *o)
{
    static const struct option longopts[] = {
        { "bind", required_argument, NULL, OPT_BIND },
        { "port", required_argument, NULL, OPT_PORT },
        { "io", required_argument, NULL, OPT_IO },
        { "io-device", required_argument, NULL, OPT_IO_DEVICE },
        { "retain", required_argument, NULL, OPT_RETAIN },
        { "retain-interval", required_argument, NULL, OPT_RETAIN_INTERVAL },
        { "retain-registers", required_argument, NULL, OPT_RETAIN_REGISTERS },
        { "allow", required_argument, NULL, OPT_ALLOW },
        { "max-clients", required_argument, NULL, OPT_MAX_CLIENTS },
        { "frame-timeout", required_argument, NULL, OPT_FRAME_TIMEOUT },
        { "read-only", no_argument, NULL, OPT_READ_ONLY },
        { "writable-coils", required_argument, NULL, OPT_WRITABLE_COILS },
        { "writable-registers", required_argument, NULL, OPT_WRITABLE_REGISTERS },
        { "host-coils", required_argument, NULL, OPT_HOST_COILS },
        { "host-registers", required_argument, NULL, OPT_HOST_REGISTERS },
        { "no-rt", no_argument, NULL, OPT_NO_RT },
        { "rt-priority", required_argument, NULL, OPT_RT_PRIORITY },
        { "cpu", required_argument, NULL, OPT_CPU },
        { "cpu-latency", required_argument, NULL, OPT_CPU_LATENCY },
        { "status", required_argument, NULL, OPT_STATUS },
        { "status-interval", required_argument, NULL, OPT_STATUS_INTERVAL },
        { "duration", required_argument, NULL, OPT_DURATION },
        { "watchdog", required_argument, NULL, OPT_WATCHDOG },
        { "describe-retain", no_argument, NULL, OPT_DESCRIBE_RETAIN },
        { "monitor", required_argument, NULL, OPT_MONITOR },
        { "monitor-token", required_argument, NULL, OPT_MONITOR_TOKEN },
        { "audit", required_argument, NULL, OPT_AUDIT },
        { "events", required_argument, NULL, OPT_EVENTS },
        { "sim-flag", required_argument, NULL, OPT_SIM_FLAG },
        { "tls-cert", required_argument, NULL, OPT_TLS_CERT },
        { "tls-key", required_argument, NULL, OPT_TLS_KEY },
        { "tls-ca", required_argument, NULL, OPT_TLS_CA },
        { "tls-bind", required_argument, NULL, OPT_TLS_BIND },
        { "tls-port", required_argument, NULL, OPT_TLS_PORT },
        { "version", no_argument, NULL, OPT_VERSION },
        { "help", no_argument, NULL, OPT_HELP },
        { NULL, 0, NULL, 0 },
    };
    char err[160];
    long v;
    int c, rc;
    bool host_coils = false, host_registers = false;

    memset(o, 0, sizeof *o);
    snprintf(o->bind, sizeof o->bind, "127.0.0.1");
    o->port = DEFAULT_PORT;
    o->tls_port = DEFAULT_TLS_PORT;
    o->io = &io_sim_layer;
    o->retain_interval_ms = DEFAULT_RETAIN_INTERVAL_MS;
    o->max_clients = DEFAULT_MAX_CLIENTS;
    o->frame_timeout_ms = DEFAULT_FRAME_TIMEOUT_MS;
    o->realtime = true;
    o->rt_priority = DEFAULT_RT_PRIORITY;
    o->cpu = -1;
    o->sim_flag_bit = -1;
    o->cpu_latency_us = -1;
    o->status = STATUS_AUTO;
    o->status_interval_s = 10;
    o->watchdog_ms = DEFAULT_WATCHDOG_MS;
    addr_set_parse(&o->writable_coils, DEFAULT_WRITABLE_COILS, MAP_BITS, err, sizeof err);
    addr_set_parse(&o->writable_registers, DEFAULT_WRITABLE_REGISTERS, MAP_HOLDING, err, sizeof err);

    opterr = 0;
    while ((c = getopt_long(argc, argv, "", longopts, NULL)) != -1) {
        switch (c) {
        case OPT_BIND:
            if (!copy_ipv4(o->bind, sizeof o->bind, optarg))
                return usage_error("--bind: '%s' is not an IPv4 address", optarg);
            break;
        case OPT_PORT:
            if (!parse_long(optarg, 0, 65535, &v))
                return usage_error("--port: '%s' is not a port number 0..65535", optarg);
            o->port = (int)v;
            break;
        case OPT_TLS_BIND:
            if (!copy_ipv4(o->tls_bind, sizeof o->tls_bind, optarg))
                return usage_error("--tls-bind: '%s' is not an IPv4 address", optarg);
            break;
        case OPT_TLS_PORT:
            if (!parse_long(optarg, 0, 65535, &v))
                return usage_error("--tls-port: '%s' is not a port number 0..65535", optarg);
            o->tls_port = (int)v;
            break;
        case OPT_TLS_CERT:
            o->tls_cert = optarg;
            break;
        case OPT_TLS_KEY:
            o->tls_key = optarg;
            break;
        case OPT_TLS_CA:
            o->tls_ca = optarg;
            break;
        case OPT_IO:
            o->io = io_layer_find(optarg);
            if (o->io == NULL) {
                char text[256];
                int n = snprintf(text, sizeof text, "--io: unknown I/O layer '%s' (", optarg);
                for (const io_layer_t *const *l = io_layers; *l && n > 0 && (size_t)n < sizeof text; l++)
                    n += snprintf(text + n, sizeof text - (size_t)n, "%s%s", l == io_layers ? "" : ", ", (*l)->name);
                if (n > 0 && (size_t)n < sizeof text)
                    snprintf(text + n, sizeof text - (size_t)n, ")");
                return usage_error("%s", text);
            }
            break;
        case OPT_IO_DEVICE:
            if (o->n_io_devices >= (int)IO_MAX_DEVICES)
                return usage_error("--io-device: more than %s devices", "16");
            o->io_devices[o->n_io_devices++] = optarg;
            break;
        case OPT_RETAIN:
            o->retain_path = optarg;
            break;
        case OPT_RETAIN_INTERVAL:
            if (!parse_long(optarg, 0, 3600000, &v))
                return usage_error("--retain-interval: '%s' is not a number of milliseconds", optarg);
            o->retain_interval_ms = (int)v;
            break;
        case OPT_RETAIN_REGISTERS:
            if ((rc = parse_set(&o->retain_registers, optarg, MAP_HOLDING, "--retain-registers")) != 0)
                return rc;
            o->have_retain_registers = strcmp(optarg, "none") != 0;
            break;
        case OPT_ALLOW: {
            char why[160];
            if (add_allow(o, optarg, why, sizeof why) != 0)
                return usage_error("--allow: %s (expected ADDR[/BITS][=read|host|engineer], ...)", why);
            break;
        }
        case OPT_MAX_CLIENTS:
            if (!parse_long(optarg, 1, 256, &v))
                return usage_error("--max-clients: '%s' is not a number 1..256", optarg);
            o->max_clients = (int)v;
            break;
        case OPT_FRAME_TIMEOUT:
            if (!parse_long(optarg, 1, 3600000, &v))
                return usage_error("--frame-timeout: '%s' is not a number of milliseconds 1..3600000", optarg);
            o->frame_timeout_ms = (int)v;
            break;
        case OPT_READ_ONLY:
            o->read_only = true;
            break;
        case OPT_WRITABLE_COILS:
            if ((rc = parse_set(&o->writable_coils, optarg, MAP_BITS, "--writable-coils")) != 0)
                return rc;
            break;
        case OPT_WRITABLE_REGISTERS:
            if ((rc = parse_set(&o->writable_registers, optarg, MAP_HOLDING, "--writable-registers")) != 0)
                return rc;
            break;
        case OPT_HOST_COILS:
            if ((rc = parse_set(&o->host_coils, optarg, MAP_BITS, "--host-coils")) != 0)
                return rc;
            host_coils = true;
            break;
        case OPT_HOST_REGISTERS:
            if ((rc = parse_set(&o->host_registers, optarg, MAP_HOLDING, "--host-registers")) != 0)
                return rc;
            host_registers = true;
            break;
        case OPT_NO_RT:
            o->realtime = false;
            break;
        case OPT_RT_PRIORITY:
            if (!parse_long(optarg, 1, 98, &v))   /* 99 is the watchdog's, above a scan at 98 */
                return usage_error("--rt-priority: '%s' is not a number 1..98", optarg);
            o->rt_priority = (int)v;
            break;
        case OPT_CPU:
            if ((rc = parse_cpu(optarg, &o->cpu)) != 0)
                return rc;
            break;
        case OPT_CPU_LATENCY:
            if (!parse_long(optarg, 0, 2000000000, &v))
                return usage_error("--cpu-latency: '%s' is not a number of microseconds 0..2000000000", optarg);
            o->cpu_latency_us = (int)v;
            break;
        case OPT_STATUS:
            if (strcmp(optarg, "auto") == 0) o->status = STATUS_AUTO;
            else if (strcmp(optarg, "tty") == 0) o->status = STATUS_TTY;
            else if (strcmp(optarg, "log") == 0) o->status = STATUS_LOG;
            else if (strcmp(optarg, "off") == 0) o->status = STATUS_OFF;
            else return usage_error("--status: '%s' is not auto, tty, log or off", optarg);
            break;
        case OPT_STATUS_INTERVAL:
            if (!parse_double(optarg, 0.1, &o->status_interval_s))
                return usage_error("--status-interval: '%s' is not a number of seconds >= 0.1", optarg);
            break;
        case OPT_DURATION:
            if (!parse_double(optarg, 0.0, &o->duration_s))
                return usage_error("--duration: '%s' is not a number of seconds", optarg);
            break;
        case OPT_WATCHDOG:
            if (!parse_long(optarg, 0, 3600000, &v))
                return usage_error("--watchdog: '%s' is not a number of milliseconds", optarg);
            o->watchdog_ms = (int)v;
            break;
        case OPT_DESCRIBE_RETAIN:
            o->describe_retain = true;
            break;
        case OPT_MONITOR:
            o->monitor_path = optarg;
            break;
        case OPT_MONITOR_TOKEN:
            o->monitor_token_file = optarg;
            break;
        case OPT_AUDIT:
            o->audit_path = optarg;
            break;
        case OPT_SIM_FLAG:
            if ((rc = parse_discrete_input(optarg, &o->sim_flag_bit)) != 0)
                return rc;
            break;
        case OPT_EVENTS:
            o->events_path = optarg;
            break;
        case OPT_VERSION:
            printf(RT_NAME " " RT_VERSION " (ABI %u)\n", PLC_ABI_VERSION);
            exit(0);
        case OPT_HELP:
            usage(stdout);
            exit(0);
        default:
            return usage_error("unknown or incomplete option '%s'", argv[optind - 1]);
        }
    }
    if (optind < argc)
        return usage_error("unexpected argument '%s'", argv[optind]);
    /* A host writes within what is writable at all: by default all of it, else the part given. */
    for (size_t i = 0; i < sizeof o->host_coils.bits / sizeof o->host_coils.bits[0]; i++) {
        o->host_coils.bits[i] = host_coils ? o->host_coils.bits[i] & o->writable_coils.bits[i]
                                           : o->writable_coils.bits[i];
        o->host_registers.bits[i] = host_registers ? o->host_registers.bits[i] & o->writable_registers.bits[i]
                                                   : o->writable_registers.bits[i];
    }
    if ((o->tls_cert != NULL) != (o->tls_key != NULL) || (o->tls_cert != NULL) != (o->tls_ca != NULL))
        return usage_error("--tls-cert, --tls-key and --tls-ca go together (the TLS listener needs all three)%s", "");
    if (!o->tls_bind[0])
        snprintf(o->tls_bind, sizeof o->tls_bind, "%s", o->bind);
    if (o->tls_cert && o->tls_port == o->port && o->port != 0 && strcmp(o->tls_bind, o->bind) == 0)
        return usage_error("--tls-port: %s is the plain listener's port too", o->bind);
    if (o->n_io_devices > 0 && o->io != &io_modbus_layer)
        return usage_error("--io-device needs --io modbus (I/O layer '%s' has no devices)", o->io->name);
    if (o->n_io_devices == 0 && o->io == &io_modbus_layer)
        return usage_error("--io modbus needs at least one --io-device%s", "");
    return 0;
}

/* ------------------------------------------------------------- program */

static int check_program(runtime_t *rt)
{
    const plc_program_t *p = rt->prog;

    if (p->abi_version != PLC_ABI_VERSION) {
        log_msg(rt->log, LOG_ERROR, "program built for ABI %u, this runtime speaks ABI %u", p->abi_version,
                PLC_ABI_VERSION);
        return -1;
    }
    if (!p->init || !p->run || !p->clock_ns || (p->n_located && !p->located) || (p->n_vars && !p->vars)) {
        log_msg(rt->log, LOG_ERROR, "program description incomplete (init, run, clock or tables missing)");
        return -1;
    }
    rt->period_ns = p->base_tick_ns;
    if (rt->period_ns == 0) {
        rt->period_ns = FALLBACK_TICK_NS;
        log_msg(rt->log, LOG_WARN, "program declares no task interval; scanning every %.0f ms",
                FALLBACK_TICK_NS / 1e6);
    }
    for (uint32_t i = 0; i < p->n_tasks; i++) {
        const plc_task_t *t = &p->tasks[i];
        log_msg(rt->log, LOG_INFO, "task %s: every %" PRIu64 " us (%u base ticks), priority %d",
                t->name ? t->name : "?", (uint64_t)t->interval_ns / 1000u, t->every, t->priority);
    }
    return 0;
}

int main(int argc, char **argv)
{
    static runtime_t rt;      /* large (images, histograms): static storage, passed by pointer */
    char err[256];
    int rc, status = 1;
    sigset_t block;

    rc = parse_options(argc, argv, &rt.opt);
    if (rc != 0)
        return rc;
    rt.prog = &plc_program;
    rt.cpu_latency_fd = -1;
    if (rt.opt.describe_retain) {
        if (rt.prog->abi_version != PLC_ABI_VERSION) {
            fprintf(stderr, RT_NAME ": error: program built for ABI %u, this runtime speaks ABI %u\n",
                    rt.prog->abi_version, PLC_ABI_VERSION);
            return 1;
        }
        return retain_describe(&rt, stdout) == 0 && fflush(stdout) == 0 ? 0 : 1;
    }
    rt_mutex_init(&rt.lock);
    rt_mutex_init(&rt.io_lock);
    rt.scan_thread = pthread_self();

    /* Every thread created from here on inherits the blocked signals. */
    sigemptyset(&block);
    sigaddset(&block, SIGINT);
    sigaddset(&block, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &block, NULL);
    signal(SIGPIPE, SIG_IGN);

    if (log_open(&rt, &rt.log) != 0) {
        fprintf(stderr, RT_NAME ": error: cannot start the log thread\n");
        return 1;
    }
    log_msg(rt.log, LOG_INFO, RT_NAME " " RT_VERSION ", program %s, I/O layer %s (%s)",
            rt.prog->config_name ? rt.prog->config_name : "?", rt.opt.io->name, rt.opt.io->description);
    if (check_program(&rt) != 0)
        goto out_log;
    if (notify_open(&rt, &rt.notify) != 0)
        goto out_log;

    rt.prog->init();
    if (image_bind_program(&rt, err, sizeof err) != 0) {
        log_msg(rt.log, LOG_ERROR, "%s", err);
        goto out_log;
    }
    if (rt.opt.io->open(&rt, &rt.io_state, err, sizeof err) != 0) {
        log_msg(rt.log, LOG_ERROR, "I/O layer %s: %s", rt.opt.io->name, err);
        goto out_log;
    }
    if (rt.opt.io == &io_sim_layer)
        rt.flags |= DIAG_FLAG_SIM_IO;
    if (modbus_server_check_tls(&rt) != 0)      /* a certificate or key that does not load: nothing written */
        goto out_io;
    if (modbus_server_probe(&rt) != 0) {        /* e.g. the port is taken: an environment problem, nothing written */
        status = 2;
        goto out_io;
    }
    if (retain_open(&rt, &rt.retain) != 0)
        goto out_io;

    pthread_mutex_lock(&rt.lock);
    image_publish_all(&rt);
    pthread_mutex_unlock(&rt.lock);

    if (events_open(&rt, rt.opt.events_path, &rt.events) != 0)
        goto out_retain;
    if (audit_open(&rt, &rt.audit) != 0)          /* named above; the writes still go to the log */
        log_msg(rt.log, LOG_WARN, "audit: no audit file: writes are told on the log only");
    if (monitor_start(&rt, &rt.monitor) != 0)      /* watching is a comfort: the PLC runs without it */
        log_msg(rt.log, LOG_WARN, "monitor: not available (the reason is above); the PLC runs without "
                "watch and force");
    if (modbus_server_start(&rt, &rt.server) != 0) {
        status = 2;                             /* taken since the probe: still the environment */
        goto out_retain;
    }

    if (watchdog_start(&rt, &rt.watchdog) != 0) {
        log_msg(rt.log, LOG_ERROR, "cannot start the watchdog thread");
        modbus_server_stop(rt.server);
        goto out_retain;
    }
    scan_setup_realtime(&rt);
    status = scan_run(&rt);
    scan_release_realtime(&rt);
    watchdog_stop(rt.watchdog);

    /* Outputs are safe now; flush retained data before anything else. */
    retain_close(&rt);
    modbus_server_stop(rt.server);
    monitor_stop(rt.monitor);
    goto out_io;
out_retain:
    monitor_stop(rt.monitor);
    retain_close(&rt);
out_io:
    rt.opt.io->close(rt.io_state);
out_log:
    audit_close(rt.audit);
    force_destroy(rt.force);
    events_close(rt.events);
    notify_close(rt.notify);
    if (status == 0)
        log_msg(rt.log, LOG_INFO, "stopped");
    log_close(rt.log);
    pthread_mutex_destroy(&rt.lock);
    pthread_mutex_destroy(&rt.io_lock);
    return status;
}
