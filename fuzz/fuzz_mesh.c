/* libFuzzer harness for the mesh reader (sim/mesh_io.c: Gmsh MSH 4.1 and 2.2 ASCII), the
 * reader behind ns.tissue.file{}. A malformed file must be an error ("path:line: ..."), never
 * a crash, a sanitizer report, a leak, a hang or a runaway allocation.
 *
 *     build-fuzz/fuzz/fuzz_mesh fuzz/corpus/mesh -dict=fuzz/mesh.dict     (tools/fuzz.sh) */
#include "fuzz_file.h"
#include "mesh_io.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    const char *path = fuzz_write_file("input.msh", data, size);
    NsMesh m;
    char err[1024] = "";
    if (ns_mesh_read_msh(path, &m, err, (int)sizeof err) == 0)
        ns_mesh_free(&m);
    else if (memchr(err, '\0', sizeof err) == NULL)
        abort(); /* the message must be a terminated string */
    fuzz_report(err);
    unlink(path);
    return 0;
}
