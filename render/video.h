/* MP4 (H.264, yuv420p) output through the ffmpeg program: raw rgb24 frames go down a pipe to an
 * ffmpeg child (started with fork/execv, no shell), whose error output is kept in an unlinked
 * temporary file so that a failure can quote its last line. */
#ifndef NS_VIDEO_H
#define NS_VIDEO_H

#include "image.h"

typedef struct NsVideo NsVideo;

/* 1 if an executable regular file `ffmpeg` is found on PATH (searched here, no shell), else 0. */
int ns_video_have_ffmpeg(void);

/* Starts ffmpeg encoding w x h frames (both even, 2..16384) at fps (0 < fps <= 1000) frames per
 * second into the MP4 file at exactly path (the caller picks a temporary name; `-f mp4` is
 * passed, so any extension works). Returns NULL with a message in err. */
NsVideo *ns_video_open(const char *path, int w, int h, double fps, char *err, int err_sz);

/* Sends one frame; im must be w x h. SIGPIPE is blocked for the write, so a dead ffmpeg gives -1
 * with its last error line (v must then still be closed or aborted). */
int ns_video_frame(NsVideo *v, const NsImage *im, char *err, int err_sz);

/* Closes the pipe, waits for ffmpeg and frees v. Returns 0, or -1 with ffmpeg's last error line
 * if it failed (the caller removes the file). */
int ns_video_close(NsVideo *v, char *err, int err_sz);

/* Kills ffmpeg (a failed run), waits for it and frees v; NULL is ignored. The caller removes the
 * file. */
void ns_video_abort(NsVideo *v);

/* Copies the MP4 at in to out (streams copied, not encoded again) with n chapters: chapter i
 * titled titles[i] from start_s[i] to the next one's start (the last to end_s) [s], in
 * ffmpeg's metadata format through its stdin. Returns 0, or -1 with ffmpeg's last error line
 * (the caller removes out). */
int ns_video_chapters(const char *in, const char *out, const char *const *titles,
                      const double *start_s, int n, double end_s, char *err, int err_sz);

#endif
