/* DIR/path.csv: a planned tip path, one point a line, written by `needlesim plan -o DIR` and
 * read by `needlesim run --plan DIR`, whose frames draw it (docs/planning.md, "The plan in the
 * frames"). The format: the header `x_m,y_m,z_m`, then 2 to NS_PLAN_PATH_MAX_POINTS lines of
 * three finite numbers [m], at most NS_PLAN_PATH_MAX_ABS from the origin each. */
#ifndef NS_PLAN_PATH_CSV_H
#define NS_PLAN_PATH_CSV_H

#include <stdio.h>

#define NS_PLAN_PATH_MAX_POINTS 100000
#define NS_PLAN_PATH_MAX_ABS    10.0 /* [m] */

/* Writes the header and the points (n x 3) to f; 0, or -1 when f reports an error. */
int ns_plan_path_csv_write(FILE *f, const double *xyz, int n);

/* Reads path (a regular file, size bounded) into *xyz (malloc'd, *n x 3). Returns 0, or -1 with
 * "path:LINE: what is wrong" in err and nothing allocated. */
int ns_plan_path_csv_read(const char *path, double **xyz, int *n, char *err, int err_sz);

#endif
