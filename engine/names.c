/* Names in CSV and JSON (names.h). */
#include "names.h"

#include <stdio.h>
#include <string.h>

#include "err.h"
#include "ns_limits.h"

#define NAME_RULE "1 to 64 bytes of printable ASCII without ',', '\"' or '\\' (spaces are fine)"

int ns_name_check(const char *name, char *why, int why_sz)
{
    size_t n = strlen(name);
    if (n == 0) {
        ns_set_err(why, why_sz, "it is empty");
        return -1;
    }
    if (n > NS_LIMIT_NAME_LENGTH) {
        ns_set_err(why, why_sz, "it is %zu bytes long", n);
        return -1;
    }
    for (size_t i = 0; i < n; i++) {
        unsigned char c = (unsigned char)name[i];
        if (c < 0x20 || c > 0x7e) {
            ns_set_err(why, why_sz, "byte %zu is 0x%02x", i + 1, c);
            return -1;
        }
        if (c == ',' || c == '"' || c == '\\') {
            ns_set_err(why, why_sz, "byte %zu is '%c'", i + 1, c);
            return -1;
        }
    }
    return 0;
}

/* The name as a message may show it: at most 40 bytes, unprintable bytes as '?'. */
static const char *shown(const char *s, char out[48])
{
    size_t n = 0;
    for (; s[n] && n < 40; n++)
        out[n] = (unsigned char)s[n] < 0x20 || (unsigned char)s[n] > 0x7e ? '?' : s[n];
    if (s[n])
        memcpy(out + n, "...", 4);
    else
        out[n] = '\0';
    return out;
}

static int check_one(const NsScenario *sc, const char *list, int i, const char *name, char *err,
                     int err_sz)
{
    char why[64], show[48];
    if (ns_name_check(name, why, sizeof why) == 0)
        return 0;
    ns_set_err(err, err_sz, "%s: ns.scenario: %s[%d]: name must be " NAME_RULE " (got '%s': %s)",
               sc->where, list, i + 1, shown(name, show), why);
    return -1;
}

int ns_names_check_run(const NsScenario *sc, const NsRunSpec *spec, char *err, int err_sz)
{
    for (int i = 0; i < sc->region_count; i++)
        if (check_one(sc, "regions", i, sc->regions[i].name, err, err_sz))
            return -1;
    for (int i = 0; i < spec->target_count; i++)
        if (check_one(sc, "targets", i, spec->targets[i].name, err, err_sz))
            return -1;
    for (int i = 0; i < spec->marker_count; i++)
        if (check_one(sc, "markers", i, spec->markers[i].name, err, err_sz))
            return -1;
    for (int i = 0; i < spec->obstacle_count; i++)
        if (check_one(sc, "obstacles", i, spec->obstacles[i].name, err, err_sz))
            return -1;
    return 0;
}

void ns_one_line(char *s)
{
    for (; *s; s++)
        if ((unsigned char)*s < 0x20 || *s == 0x7f)
            *s = ' ';
}
