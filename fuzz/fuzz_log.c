/* libFuzzer harness for the trainee control-log reader (engine/control_log.c), the reader
 * behind `needlesim run --replay LOG.csv`. The time step is 0.01 s, the shipped scenarios'
 * (the seed logs were recorded with it), so rows can pass the t = k dt check and the fuzzer
 * reaches the event parser. The '#' lines alone are read too, as `needlesim score` reads them
 * (ns_control_log_read_provenance).
 *
 *     build-fuzz/fuzz/fuzz_log fuzz/corpus/log -dict=fuzz/log.dict     (tools/fuzz.sh) */
#include "control_log.h"
#include "fuzz_file.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    const char *path = fuzz_write_file("input.csv", data, size);
    NsControlLog log;
    char err[1024] = "";
    if (ns_control_log_read(path, 0.01, &log, err, (int)sizeof err) == 0) {
        if (log.n <= 0 || !log.rows || log.nsets < 0 || log.nsets > NS_CONTROL_LOG_MAX_SETS)
            abort();
        ns_control_log_free(&log);
    } else if (memchr(err, '\0', sizeof err) == NULL) {
        abort();
    }
    fuzz_report(err);
    char perr[1024] = "";
    if (ns_control_log_read_provenance(path, &log, perr, (int)sizeof perr) == 0) {
        if (log.rows || log.nsets < 0 || log.nsets > NS_CONTROL_LOG_MAX_SETS)
            abort();
    } else if (memchr(perr, '\0', sizeof perr) == NULL) {
        abort();
    }
    unlink(path);
    return 0;
}
