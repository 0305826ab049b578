/* engine/dose_table.c: the shipped model 6711 table loads and converts to SI; malformed tables
 * are refused with the file, line and field. */
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

#include "dose_table.h"
#include "ns_config.h"
#include "ns_test.h"

static int test_shipped_6711(void)
{
    NsTg43Source s;
    char err[512] = "";
    int rc = ns_tg43_load(NS_SOURCE_DIR "/assets/" NS_TG43_6711_ASSET, &s, err, sizeof err);
    if (rc)
        fprintf(stderr, "%s\n", err);
    ENSURE(rc == 0);
    ENSURE_SMALL(s.lambda - 9650.0, 1e-9); /* 0.965 cGy h^-1 U^-1 = 0.965 cm^-2 */
    ENSURE_SMALL(s.length - 0.003, 1e-15);
    ENSURE_SMALL(s.half_life - 59.40 * 86400.0, 1e-6);
    ENSURE(s.n_g == 16 && s.n_fr == 6 && s.n_ft == 11 && s.n_phi == 6);
    ENSURE_SMALL(s.g_r[0] - 0.001, 1e-18);
    ENSURE_SMALL(s.g[15] - 0.0803, 1e-15);
    ENSURE_SMALL(s.f[0] - 0.333, 1e-15);           /* r 0.5 cm, theta 0 */
    ENSURE_SMALL(s.f_theta[10] - M_PI / 2, 1e-15); /* the last row is 90 deg */
    return 0;
}

/* Writes text to a temporary file, loads it, and expects failure with want in the message. */
static int refused(const char *text, const char *want)
{
    char path[] = "/tmp/needlesim-tg43-XXXXXX";
    int fd = mkstemp(path);
    if (fd < 0)
        return 0;
    FILE *f = fdopen(fd, "w");
    fputs(text, f);
    fclose(f);
    NsTg43Source s;
    char err[512] = "";
    int rc = ns_tg43_load(path, &s, err, sizeof err);
    unlink(path);
    if (rc == 0 || !strstr(err, want)) {
        fprintf(stderr, "wanted '%s', got rc %d: %s\n", want, rc, err);
        return 0;
    }
    return strstr(err, path) != NULL; /* the message names the file */
}

#define HEAD                                                                                       \
    "param,lambda_cGy_per_h_per_U,0.965\nparam,active_length_cm,0.3\nparam,half_life_d,59.4\n"
#define GS "g,0.5,1.0\ng,1.0,1.0\n"
#define FS "F_radii,1.0\nF,0,0.5\nF,90,1.0\n"

static int test_malformed(void)
{
    NsTg43Source s;
    char path[] = "/tmp/needlesim-tg43-XXXXXX";
    int fd = mkstemp(path);
    ENSURE(fd >= 0);
    FILE *f = fdopen(fd, "w");
    fputs("# a comment\n\n" HEAD GS FS "phi_an,1.0,0.95 # trailing comment\n", f);
    fclose(f);
    char err[512];
    int rc = ns_tg43_load(path, &s, err, sizeof err);
    unlink(path);
    ENSURE(rc == 0 && s.n_g == 2 && s.n_ft == 2 && s.n_phi == 1);

    ENSURE(refused(HEAD "g,0.5,abc\n" GS FS, ":4: field 3: not a finite number"));
    ENSURE(refused(HEAD "g,0.5,1.0\ng,0.5,1.0\n" FS, ":5: field 2: radius must be > 0"));
    ENSURE(refused(HEAD GS "F,0,0.5\n", ":6: an 'F' row before the 'F_radii' record"));
    ENSURE(refused(HEAD GS "F_radii,1.0\nF,0,0.5,0.6\n", ":7: 'F' takes 3 fields, found 4"));
    ENSURE(refused(HEAD GS "F_radii,1.0\nF,0,0.5\nF,95,1.0\n", ":8: field 2: angle must be"));
    ENSURE(refused(HEAD GS "F_radii,1.0\nF,0,0.5\nF,80,1.0\n", "anisotropy function: 2 angles"));
    ENSURE(refused(HEAD GS "F_radii,1.0\nF,0,2.5\nF,90,1.0\n", ":7: field 3: anisotropy"));
    ENSURE(refused(HEAD GS FS "dose,1\n", ":9: field 1: unknown record"));
    ENSURE(refused("param,active_length_cm,0.3\nparam,half_life_d,59.4\n" GS FS,
                   "missing param lambda_cGy_per_h_per_U"));
    ENSURE(refused(HEAD "param,half_life_d,-1\n" GS FS, ":4: field 3: must be > 0"));
    ENSURE(refused(HEAD "param,colour,1\n" GS FS, ":4: field 2: unknown parameter"));
    ENSURE(refused(HEAD "g,0.5,1e999\n" GS FS, ":4: field 3: not a finite number"));
    ENSURE(ns_tg43_load("/nonexistent/table.csv", &s, err, sizeof err) == -1);
    ENSURE(strstr(err, "/nonexistent/table.csv") != NULL);
    ENSURE(ns_tg43_load("/tmp", &s, err, sizeof err) == -1); /* a folder */
    return 0;
}

int main(int argc, char **argv)
{
    static const NsTestCase cases[] = {
        {"shipped_6711", test_shipped_6711},
        {"malformed", test_malformed},
    };
    return ns_test_main(argc, argv, cases, (int)(sizeof cases / sizeof cases[0]));
}
