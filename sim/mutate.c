/* Mutation builds only (sim/mutate.h): the factors of NS_MUTATE ("name=factor,..."). */
#include "mutate.h"

#ifdef NS_MUTATION_BUILD
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

double ns_mutation_factor(const char *name)
{
    const char *spec = getenv("NS_MUTATE");
    if (!spec || !*spec)
        return 1.0;
    size_t len = strlen(name);
    for (const char *p = spec; *p;) {
        const char *eq = strchr(p, '=');
        if (!eq) {
            fprintf(stderr, "NS_MUTATE: expected name=factor in '%s'\n", spec);
            exit(2);
        }
        char *end;
        double f = strtod(eq + 1, &end);
        if (end == eq + 1 || (*end && *end != ',') || !(f > 0.0)) {
            fprintf(stderr, "NS_MUTATE: bad factor in '%s'\n", spec);
            exit(2);
        }
        if ((size_t)(eq - p) == len && strncmp(p, name, len) == 0)
            return f;
        p = *end ? end + 1 : end;
    }
    return 1.0;
}
#endif
