/* The live session's message parser (engine/live_protocol.c) on good and hostile input. */
#include "live_protocol.h"
#include "scene.h"
#include "ns_limits.h"
#include "ns_test.h"

#include <stdlib.h>

static int parse(const char *s, NsLiveMsg *m)
{
    char err[256];
    return ns_live_parse(s, strlen(s), m, err, sizeof err);
}

static int good_messages(void)
{
    NsLiveMsg m;
    ENSURE(parse("{\"insert_speed\": 0.01}", &m) == 0);
    ENSURE(m.has == NS_LIVE_INSERT_SPEED && m.insert_speed == 0.01);
    ENSURE(parse(" {\"twist_rate\":-3.5e0 } \n", &m) == 0 && m.twist_rate == -3.5);
    ENSURE(parse("{\"twist\": 3.14159}", &m) == 0 && m.has == NS_LIVE_TWIST);
    ENSURE(parse("{\"base_velocity\": [0, -0.001, 2E-3]}", &m) == 0);
    ENSURE(m.base_velocity[1] == -0.001 && m.base_velocity[2] == 0.002);
    ENSURE(parse("{\"drop_seed\": true}", &m) == 0 && m.drop_seed);
    ENSURE(parse("{\"next_needle\": true}", &m) == 0 && m.next_needle);
    ENSURE(parse("{\"pause\": false}", &m) == 0 && m.has == NS_LIVE_PAUSE && !m.pause);
    ENSURE(parse("{\"end\": true}", &m) == 0 && m.end);
    ENSURE(parse("{\"insert_speed\": 0, \"twist_rate\": 1}", &m) == 0);
    ENSURE(m.has == (NS_LIVE_INSERT_SPEED | NS_LIVE_TWIST_RATE));
    ENSURE(parse("{\"views\": \"cutaway3d,trus\"}", &m) == 0 && m.has == NS_LIVE_VIEWS);
    ENSURE(m.nviews == 2 && m.views[0] == NS_VIEW_CUTAWAY3D && m.views[1] == NS_VIEW_TRUS);
    ENSURE(parse("{\"views\": \"side\", \"pause\": true}", &m) == 0 && m.nviews == 1);
    ENSURE(parse("{\"views\": \"\"}", &m) == 0 && m.has == NS_LIVE_VIEWS && m.nviews == 0);
    /* an escaped key is the same key */
    ENSURE(parse("{\"insert\\u005fspeed\": 0.002}", &m) == 0 && m.insert_speed == 0.002);
    return 0;
}

static int hostile_messages(void)
{
    static const char *const bad[] = {
        "",
        "null",
        "[]",
        "{}",
        "{",
        "{\"insert_speed\": }",
        "{\"insert_speed\": 0.01",
        "{\"insert_speed\": 0.01}}",
        "{\"insert_speed\": 0.01} x",
        "{\"insert_speed\": \"fast\"}",
        "{\"insert_speed\": NaN}",
        "{\"insert_speed\": Infinity}",
        "{\"insert_speed\": 1e999}",
        "{\"insert_speed\": 01}",
        "{\"insert_speed\": .5}",
        "{\"insert_speed\": 1.}",
        "{\"insert_speed\": +1}",
        "{\"insert_speed\": 0x10}",
        "{\"insert_speed\": 0.6}",
        "{\"insert_speed\": -0.6}",
        "{\"insert_speed\": 0.01, \"insert_speed\": 0.02}",
        "{\"twist_rate\": 100}",
        "{\"twist\": 1000}",
        "{\"base_velocity\": [0, 0]}",
        "{\"base_velocity\": [0, 0, 0, 0]}",
        "{\"base_velocity\": [0, 0, 1]}",
        "{\"base_velocity\": 0}",
        "{\"base_velocity\": [[0], 0, 0]}",
        "{\"drop_seed\": 1}",
        "{\"drop_seed\": tru}",
        "{\"pause\": null}",
        "{\"end\": {}}",
        "{\"unknown\": 1}",
        "{insert_speed: 0.01}",
        "{'insert_speed': 0.01}",
        "{\"insert_speed\" 0.01}",
        "{\"insert_speed\": 0.01,}",
        "{,\"insert_speed\": 0.01}",
        "{\"\\x\": 1}",
        "{\"\\u00zz\": 1}",
        "{\"a\nb\": 1}",
        "{\"\xff\xfe\": 1}",
        "{\"insert_speed\": 0.01, \"pause\": true, \"end\": true, \"bogus\": 1}",
        "{\"aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa\": 1}",
        "{\"insert_speed\": 0.000000000000000000000000000000000000000000000000000000000000001}",
        "{\"views\": \",\"}",
        "{\"views\": \"echo\"}",
        "{\"views\": \"side,top,axis,trus\"}",
        "{\"views\": [\"side\"]}",
        "{\"views\": 3}",
        "{\"views\": \"side,side,side,side,side,side,side,side,side,side,side,side,side\"}",
        "{\"views\": \"side\\u0000top\"}",
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        NsLiveMsg m;
        char err[256] = "";
        if (ns_live_parse(bad[i], strlen(bad[i]), &m, err, sizeof err) == 0) {
            fprintf(stderr, "accepted: %s\n", bad[i]);
            return 1;
        }
        ENSURE(err[0] != '\0');
    }
    /* NUL inside, and a message over the size limit */
    NsLiveMsg m;
    char err[256];
    ENSURE(ns_live_parse("{\"end\": true}\0", 14, &m, err, sizeof err) != 0);
    size_t n = NS_LIMIT_LIVE_MESSAGE_BYTES + 1;
    char *big = malloc(n);
    ENSURE(big);
    memset(big, ' ', n);
    memcpy(big, "{\"end\": true}", 13);
    int rc = ns_live_parse(big, n, &m, err, sizeof err);
    free(big);
    ENSURE(rc != 0 && strstr(err, "at most"));
    return 0;
}

/* Every prefix of a good message is refused, and random bytes never crash. */
static int prefixes_and_noise(void)
{
    const char *s = "{\"base_velocity\": [0.001, -0.002, 3e-3], \"pause\": true}";
    NsLiveMsg m;
    char err[256];
    for (size_t n = 0; n < strlen(s); n++)
        ENSURE(ns_live_parse(s, n, &m, err, sizeof err) != 0);
    ENSURE(ns_live_parse(s, strlen(s), &m, err, sizeof err) == 0);
    unsigned x = 12345;
    char buf[64];
    for (int k = 0; k < 20000; k++) {
        size_t n = (size_t)(k % 64);
        for (size_t i = 0; i < n; i++) {
            x = x * 1103515245u + 12345u;
            buf[i] = "{}[]\":,.-0123456789eEtruefalsn \\u"[(x >> 16) % 33];
        }
        ns_live_parse(buf, n, &m, err, sizeof err);
    }
    return 0;
}

static int error_json(void)
{
    char out[128];
    int n = ns_live_error_json("bad \"key\" \xff", out, sizeof out);
    ENSURE(n > 0 && (size_t)n == strlen(out));
    ENSURE(strncmp(out, "{\"error\": \"bad \\\"key\\\" ", 23) == 0);
    char small[8];
    ENSURE(ns_live_error_json("too long for this", small, sizeof small) < 0);
    return 0;
}

int main(int argc, char **argv)
{
    NsTestCase cases[] = {{"good_messages", good_messages},
                          {"hostile_messages", hostile_messages},
                          {"prefixes_and_noise", prefixes_and_noise},
                          {"error_json", error_json}};
    return ns_test_main(argc, argv, cases, (int)(sizeof cases / sizeof cases[0]));
}
