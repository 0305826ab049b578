/* Names in CSV and JSON (names.h). */
#include "names.h"

#include <stdio.h>
#include <string.h>

#include "err.h"
#include "ns_limits.h"

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

void ns_one_line(char *s)
{
    for (; *s; s++)
        if ((unsigned char)*s < 0x20 || *s == 0x7f)
            *s = ' ';
}
