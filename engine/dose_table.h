/* Reading a TG-43 consensus table (the assets/tg43 CSV files; the format is in the file's header)
 * into an NsTg43Source (sim/dose.h), converted to SI: cm -> m, deg -> rad, cGy h^-1 U^-1 -> m^-2,
 * days -> s. */
#ifndef NS_DOSE_TABLE_H
#define NS_DOSE_TABLE_H

#include "dose.h"

/* The shipped I-125 model 6711 table, relative to the assets folder. */
#define NS_TG43_6711_ASSET "tg43/i125_6711.csv"

/* Reads path into s. Returns 0, or -1 with "path:line: field N: what is wrong" (or "path: ...")
 * in err; every number is checked (finite, in range, tables increasing) and the whole source
 * passes ns_tg43_check. */
int ns_tg43_load(const char *path, NsTg43Source *s, char *err, int err_sz);

/* ns_tg43_load of the shipped model 6711 table (engine/data_dir.h's assets folder). */
int ns_tg43_load_6711(NsTg43Source *s, char *err, int err_sz);

#endif
