/* The world's snapshots (sim/snapshot.h): the layout fingerprint and the world packed whole,
 * apart from the stream (snapshot.c) so that the structures' files, which include snapshot.h,
 * are not included back by it (tools/include_cycles.py). */
#include "snapshot.h"

#include <stdlib.h>
#include <string.h>

#include "coupling.h"
#include "mesh.h"
#include "remesh.h"
#include "rod.h"
#include "tissue.h"

static const uint64_t FNV_OFFSET = 14695981039346656037ULL;
static const uint64_t FNV_PRIME = 1099511628211ULL;

uint64_t ns_pack_fingerprint(void)
{
    const size_t sizes[] = {
        sizeof(NsMesh),      sizeof(NsTissue),      sizeof(NsTissueParams),   sizeof(NsRod),
        sizeof(NsRodParams), sizeof(NsCoupled),     sizeof(NsCouplingParams), sizeof(NsRemeshStack),
        sizeof(NsRemeshOp),  sizeof(NsBlockMatrix), sizeof(NsBanded),         sizeof(void *)};
    uint64_t h = FNV_OFFSET;
    const unsigned char *b = (const unsigned char *)sizes;
    for (size_t i = 0; i < sizeof sizes; i++) {
        h ^= b[i];
        h *= FNV_PRIME;
    }
    return h;
}

int ns_world_pack(NsPack *p, NsTissue *t, NsRod *r, NsCoupled *c)
{
    ns_pack_tag(p, "NSWD");
    uint64_t fp = ns_pack_fingerprint(), fp_read = fp;
    NS_PACK(p, fp_read);
    if (!p->writing && !p->failed && fp_read != fp)
        ns_pack_fail(p,
                     "written by a build whose structures differ (layout %016llx, this build's "
                     "%016llx)",
                     (unsigned long long)fp_read, (unsigned long long)fp);
    /* A failed stream does nothing, so each pack below still leaves its structure freeable. */
    ns_tissue_pack(p, t);
    ns_rod_pack(p, r);
    ns_coupled_pack(p, c, t, r);
    ns_pack_checksum(p);
    return p->failed ? -1 : 0;
}

static void set_err(char *err, int err_sz, const char *what, const NsPack *p)
{
    if (err && err_sz > 0)
        snprintf(err, (size_t)err_sz, "%s: %s", what, p->err);
}

int ns_world_snapshot(NsTissue *t, NsRod *r, NsCoupled *c, NsWorldSnapshot *s, char *err,
                      int err_sz)
{
    NsPack p;
    ns_pack_writer(&p, NULL);
    s->bytes = NULL;
    s->len = 0;
    if (ns_world_pack(&p, t, r, c) != 0) {
        set_err(err, err_sz, "snapshot", &p);
        ns_pack_free(&p);
        return -1;
    }
    s->bytes = p.buf; /* taken over from the writer */
    s->len = p.len;
    return 0;
}

int ns_world_restore(const NsWorldSnapshot *s, NsTissue *t, NsRod *r, NsCoupled *c, char *err,
                     int err_sz)
{
    NsPack p;
    ns_pack_reader(&p, NULL, s->bytes, s->len);
    int rc = ns_world_pack(&p, t, r, c);
    if (rc != 0)
        set_err(err, err_sz, "restore", &p);
    ns_pack_free(&p);
    return rc;
}

void ns_world_snapshot_free(NsWorldSnapshot *s)
{
    free(s->bytes);
    s->bytes = NULL;
    s->len = 0;
}
