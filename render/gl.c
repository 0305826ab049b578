/* EGL context and OpenGL 3.3 core drawing of NsScene views (render/gl.h). The sim never sees
 * GL: everything drawn comes in as plain vertex lists. */
#define GL_GLEXT_PROTOTYPES 1
#include "gl.h"

#include <EGL/egl.h>
#include <EGL/eglext.h>
#include <GL/glcorearb.h>
#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"

struct NsRenderer {
    int w, h, samples;
    EGLDisplay dpy;
    EGLContext ctx;
    GLuint fbo_ms, rb_color, rb_depth, fbo_rs, rb_rs;
    GLuint prog, vao, vbo;
    GLint u_mvp, u_plane, u_clip, u_lit, u_alpha, u_light;
    uint8_t *rgba; /* read-back buffer */
    char info[256];
};

/* ---- EGL ---- */

static bool has_ext(const char *list, const char *name)
{
    size_t n = strlen(name);
    for (const char *p = list; p && (p = strstr(p, name)); p += n)
        if ((p == list || p[-1] == ' ') && (p[n] == ' ' || p[n] == '\0'))
            return true;
    return false;
}

/* Initializes dpy and makes a GL 3.3 core context current on it with no surface. */
static bool make_context(NsRenderer *r, EGLDisplay dpy)
{
    EGLint major, minor;
    if (dpy == EGL_NO_DISPLAY || !eglInitialize(dpy, &major, &minor))
        return false;
    if (!eglBindAPI(EGL_OPENGL_API)) {
        eglTerminate(dpy);
        return false;
    }
    const EGLint cfg_attr[] = {EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_NONE};
    EGLConfig cfg = NULL;
    EGLint n = 0;
    eglChooseConfig(dpy, cfg_attr, &cfg, 1, &n);
    const EGLint ctx_attr[] = {EGL_CONTEXT_MAJOR_VERSION,
                               3,
                               EGL_CONTEXT_MINOR_VERSION,
                               3,
                               EGL_CONTEXT_OPENGL_PROFILE_MASK,
                               EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT,
                               EGL_NONE};
    EGLContext ctx = eglCreateContext(dpy, n > 0 ? cfg : (EGLConfig)0, EGL_NO_CONTEXT, ctx_attr);
    if (ctx == EGL_NO_CONTEXT || !eglMakeCurrent(dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, ctx)) {
        if (ctx != EGL_NO_CONTEXT)
            eglDestroyContext(dpy, ctx);
        eglTerminate(dpy);
        return false;
    }
    r->dpy = dpy;
    r->ctx = ctx;
    return true;
}

/* The EGL device platform on a hardware device, else Mesa's surfaceless platform. */
static const char *open_display(NsRenderer *r, char *err, int err_sz)
{
    const char *mode = getenv("NEEDLESIM_EGL");
    const char *client = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
    PFNEGLGETPLATFORMDISPLAYEXTPROC get_display =
        (PFNEGLGETPLATFORMDISPLAYEXTPROC)eglGetProcAddress("eglGetPlatformDisplayEXT");
    if (!client || !get_display) {
        ns_set_err(err, err_sz,
                   "EGL has no platform displays (libEGL without EGL_EXT_platform_base; install "
                   "libegl1 and libegl-mesa0)");
        return NULL;
    }
    bool want_surfaceless = mode && strcmp(mode, "surfaceless") == 0;
    if (!want_surfaceless && has_ext(client, "EGL_EXT_device_enumeration") &&
        has_ext(client, "EGL_EXT_platform_device")) {
        PFNEGLQUERYDEVICESEXTPROC query =
            (PFNEGLQUERYDEVICESEXTPROC)eglGetProcAddress("eglQueryDevicesEXT");
        PFNEGLQUERYDEVICESTRINGEXTPROC query_str =
            (PFNEGLQUERYDEVICESTRINGEXTPROC)eglGetProcAddress("eglQueryDeviceStringEXT");
        EGLDeviceEXT dev[16];
        EGLint nd = 0;
        if (query && query_str && query(16, dev, &nd))
            for (int i = 0; i < nd; i++) {
                const char *ext = query_str(dev[i], EGL_EXTENSIONS);
                if (has_ext(ext, "EGL_MESA_device_software"))
                    continue; /* llvmpipe: the surfaceless platform below is the same */
                if (make_context(r, get_display(EGL_PLATFORM_DEVICE_EXT, dev[i], NULL)))
                    return "device";
            }
    }
    if (mode && strcmp(mode, "device") == 0) {
        ns_set_err(err, err_sz, "NEEDLESIM_EGL=device: no EGL hardware device gave a context");
        return NULL;
    }
    if (has_ext(client, "EGL_MESA_platform_surfaceless") &&
        make_context(r, get_display(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, NULL)))
        return "surfaceless";
    ns_set_err(err, err_sz,
               "no offscreen OpenGL 3.3 context: neither an EGL GPU device nor Mesa's surfaceless "
               "platform worked (install libegl-mesa0 and libgl1-mesa-dri, or run with "
               "--no-render)");
    return NULL;
}

/* ---- GL ---- */

static const char *vs_src =
    "#version 330 core\n"
    "layout(location = 0) in vec3 pos;\n"
    "layout(location = 1) in vec3 nrm;\n"
    "layout(location = 2) in vec4 col;\n"
    "uniform mat4 mvp;\n"
    "uniform vec4 plane;\n"
    "uniform int clip_on;\n"
    "out vec3 v_n;\n"
    "out vec4 v_c;\n"
    "void main() {\n"
    "  gl_Position = mvp * vec4(pos, 1.0);\n"
    "  gl_ClipDistance[0] = clip_on != 0 ? -dot(plane, vec4(pos, 1.0)) : 1.0;\n"
    "  v_n = nrm;\n"
    "  v_c = col;\n"
    "}\n";

static const char *fs_src = "#version 330 core\n"
                            "in vec3 v_n;\n"
                            "in vec4 v_c;\n"
                            "uniform int lit;\n"
                            "uniform float alpha;\n"
                            "uniform vec3 light;\n"
                            "out vec4 frag;\n"
                            "void main() {\n"
                            "  vec3 c = v_c.rgb;\n"
                            "  if (lit != 0) {\n"
                            "    vec3 n = normalize(v_n);\n"
                            "    float d = abs(dot(n, light));\n"
                            /* d^24 by squaring: llvmpipe's pow is exp2(24 log2 d) */
                            "    float d2 = d * d, d4 = d2 * d2, d8 = d4 * d4;\n"
                            "    c = c * (0.42 + 0.58 * d) + vec3(0.18) * (d8 * d8 * d8);\n"
                            "  }\n"
                            "  frag = vec4(min(c, vec3(1.0)), v_c.a * alpha);\n"
                            "}\n";

static GLuint compile(GLenum kind, const char *src, char *err, int err_sz)
{
    GLuint s = glCreateShader(kind);
    glShaderSource(s, 1, &src, NULL);
    glCompileShader(s);
    GLint ok = 0;
    glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
    if (!ok) {
        char log[512] = "";
        glGetShaderInfoLog(s, sizeof log, NULL, log);
        ns_set_err(err, err_sz, "shader compile failed: %s", log);
        glDeleteShader(s);
        return 0;
    }
    return s;
}

static int gl_setup(NsRenderer *r, char *err, int err_sz)
{
    GLuint vs = compile(GL_VERTEX_SHADER, vs_src, err, err_sz);
    GLuint fs = vs ? compile(GL_FRAGMENT_SHADER, fs_src, err, err_sz) : 0;
    if (!fs) {
        if (vs)
            glDeleteShader(vs);
        return -1;
    }
    r->prog = glCreateProgram();
    glAttachShader(r->prog, vs);
    glAttachShader(r->prog, fs);
    glLinkProgram(r->prog);
    glDeleteShader(vs);
    glDeleteShader(fs);
    GLint ok = 0;
    glGetProgramiv(r->prog, GL_LINK_STATUS, &ok);
    if (!ok) {
        ns_set_err(err, err_sz, "shader link failed");
        return -1;
    }
    r->u_mvp = glGetUniformLocation(r->prog, "mvp");
    r->u_plane = glGetUniformLocation(r->prog, "plane");
    r->u_clip = glGetUniformLocation(r->prog, "clip_on");
    r->u_lit = glGetUniformLocation(r->prog, "lit");
    r->u_alpha = glGetUniformLocation(r->prog, "alpha");
    r->u_light = glGetUniformLocation(r->prog, "light");
    glGenVertexArrays(1, &r->vao);
    glBindVertexArray(r->vao);
    glGenBuffers(1, &r->vbo);
    glBindBuffer(GL_ARRAY_BUFFER, r->vbo);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, sizeof(NsVertex),
                          (void *)offsetof(NsVertex, p));
    glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, sizeof(NsVertex),
                          (void *)offsetof(NsVertex, n));
    glVertexAttribPointer(2, 4, GL_UNSIGNED_BYTE, GL_TRUE, sizeof(NsVertex),
                          (void *)offsetof(NsVertex, rgba));
    for (int i = 0; i < 3; i++)
        glEnableVertexAttribArray((GLuint)i);

    /* the multisampled frame, and a single-sampled one it resolves into for reading; with one
     * sample the frame is single-sampled and read directly */
    int ms = r->samples > 1 ? r->samples : 0;
    glGenFramebuffers(1, &r->fbo_ms);
    glBindFramebuffer(GL_FRAMEBUFFER, r->fbo_ms);
    glGenRenderbuffers(1, &r->rb_color);
    glBindRenderbuffer(GL_RENDERBUFFER, r->rb_color);
    glRenderbufferStorageMultisample(GL_RENDERBUFFER, ms, GL_RGBA8, r->w, r->h);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, r->rb_color);
    glGenRenderbuffers(1, &r->rb_depth);
    glBindRenderbuffer(GL_RENDERBUFFER, r->rb_depth);
    glRenderbufferStorageMultisample(GL_RENDERBUFFER, ms, GL_DEPTH_COMPONENT24, r->w, r->h);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, r->rb_depth);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        ns_set_err(err, err_sz, "the %dx%d framebuffer with %d samples is not supported", r->w,
                   r->h, r->samples);
        return -1;
    }
    glGenFramebuffers(1, &r->fbo_rs);
    glBindFramebuffer(GL_FRAMEBUFFER, r->fbo_rs);
    glGenRenderbuffers(1, &r->rb_rs);
    glBindRenderbuffer(GL_RENDERBUFFER, r->rb_rs);
    glRenderbufferStorage(GL_RENDERBUFFER, GL_RGBA8, r->w, r->h);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, r->rb_rs);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        ns_set_err(err, err_sz, "the %dx%d read-back framebuffer is not supported", r->w, r->h);
        return -1;
    }
    glBindFramebuffer(GL_FRAMEBUFFER, r->fbo_ms);
    glEnable(GL_CLIP_DISTANCE0);
    glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
    return glGetError() == GL_NO_ERROR ? 0 : (ns_set_err(err, err_sz, "OpenGL set-up failed"), -1);
}

NsRenderer *ns_renderer_open(int w, int h, int samples, char *err, int err_sz)
{
    if (w < 16 || h < 16 || w > 8192 || h > 8192) {
        ns_set_err(err, err_sz, "frame size %dx%d: expected 16..8192 pixels each way", w, h);
        return NULL;
    }
    NsRenderer *r = calloc(1, sizeof *r);
    if (r)
        r->rgba = malloc((size_t)w * h * 4);
    if (!r || !r->rgba) {
        free(r);
        ns_set_err(err, err_sz, "out of memory");
        return NULL;
    }
    r->w = w;
    r->h = h;
    r->samples = samples < 1 ? 1 : samples;
    r->dpy = EGL_NO_DISPLAY;
    const char *platform = open_display(r, err, err_sz);
    if (!platform) {
        free(r->rgba);
        free(r);
        return NULL;
    }
    snprintf(r->info, sizeof r->info, "EGL %s, %s, OpenGL %s", platform,
             (const char *)glGetString(GL_RENDERER), (const char *)glGetString(GL_VERSION));
    GLint max_samples = 1;
    glGetIntegerv(GL_MAX_SAMPLES, &max_samples);
    if (r->samples > max_samples)
        r->samples = max_samples;
    if (gl_setup(r, err, err_sz)) {
        ns_renderer_close(r);
        return NULL;
    }
    return r;
}

void ns_renderer_close(NsRenderer *r)
{
    if (!r)
        return;
    if (r->ctx) {
        glDeleteBuffers(1, &r->vbo);
        glDeleteVertexArrays(1, &r->vao);
        glDeleteProgram(r->prog);
        GLuint rbs[3] = {r->rb_color, r->rb_depth, r->rb_rs}, fbs[2] = {r->fbo_ms, r->fbo_rs};
        glDeleteRenderbuffers(3, rbs);
        glDeleteFramebuffers(2, fbs);
        eglMakeCurrent(r->dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
        eglDestroyContext(r->dpy, r->ctx);
    }
    /* The display is not terminated: EGL displays are per process and reused by the next
     * renderer, and terminating one unloads Mesa's driver, whose few remaining allocations
     * then show up as leaks of an unknown module under LeakSanitizer. */
    eglReleaseThread();
    free(r->rgba);
    free(r);
}

const char *ns_renderer_info(const NsRenderer *r)
{
    return r->info;
}

void ns_renderer_clear(NsRenderer *r, const uint8_t bg[3], int x, int w)
{
    glBindFramebuffer(GL_FRAMEBUFFER, r->fbo_ms);
    glViewport(0, 0, r->w, r->h);
    glEnable(GL_SCISSOR_TEST);
    glScissor(x, 0, w, r->h);
    glDepthMask(GL_TRUE);
    glClearColor(bg[0] / 255.0f, bg[1] / 255.0f, bg[2] / 255.0f, 1.0f);
    glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
}

static void draw_buf(NsRenderer *r, const NsVertexBuf *b, GLenum mode)
{
    if (b->n == 0)
        return;
    glBufferData(GL_ARRAY_BUFFER, (GLsizeiptr)b->n * (GLsizeiptr)sizeof(NsVertex), b->v,
                 GL_STREAM_DRAW);
    glDrawArrays(mode, 0, b->n);
    (void)r;
}

int ns_renderer_draw(NsRenderer *r, const NsScene *s, int x, int y, int w, int h, char *err,
                     int err_sz)
{
    glBindFramebuffer(GL_FRAMEBUFFER, r->fbo_ms);
    glViewport(x, r->h - y - h, w, h);
    glEnable(GL_SCISSOR_TEST);
    glScissor(x, r->h - y - h, w, h);
    glUseProgram(r->prog);
    glBindVertexArray(r->vao);
    glBindBuffer(GL_ARRAY_BUFFER, r->vbo);
    double md[16], f[3];
    float mf[16], plane[4];
    ns_camera_matrix(&s->camera, (double)w / h, md);
    for (int i = 0; i < 16; i++)
        mf[i] = (float)md[i];
    for (int i = 0; i < 4; i++)
        plane[i] = (float)s->plane[i];
    for (int i = 0; i < 3; i++)
        f[i] = s->camera.target[i] - s->camera.eye[i];
    double fl = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
    glUniformMatrix4fv(r->u_mvp, 1, GL_FALSE, mf);
    glUniform4fv(r->u_plane, 1, plane);
    glUniform3f(r->u_light, (float)(f[0] / fl), (float)(f[1] / fl), (float)(f[2] / fl));
    glEnable(GL_DEPTH_TEST);
    glDepthMask(GL_TRUE);
    glDisable(GL_BLEND);
    glUniform1f(r->u_alpha, 1.0f);
    /* 1. the cut face (pushed back a little so its edges and the needle in it win) */
    glUniform1i(r->u_clip, 0);
    glUniform1i(r->u_lit, 0);
    glDepthFunc(GL_LESS);
    glEnable(GL_POLYGON_OFFSET_FILL);
    glPolygonOffset(1.0f, 2.0f);
    draw_buf(r, &s->cap, GL_TRIANGLES);
    glDisable(GL_POLYGON_OFFSET_FILL);
    glDepthFunc(GL_LEQUAL);
    draw_buf(r, &s->edges, GL_LINES);
    /* 2. the solids: first faded where the cut face hides them (the depth buffer holds only
     * the cap), then solid over it where they show (their own back faces stay hidden) */
    glUniform1i(r->u_lit, 1);
    glEnable(GL_BLEND);
    glDepthMask(GL_FALSE);
    glDepthFunc(GL_GREATER);
    glUniform1f(r->u_alpha, 0.3f);
    draw_buf(r, &s->solid, GL_TRIANGLES);
    glDisable(GL_BLEND);
    glDepthMask(GL_TRUE);
    glDepthFunc(GL_LESS);
    glUniform1f(r->u_alpha, 1.0f);
    draw_buf(r, &s->solid, GL_TRIANGLES);
    glEnable(GL_BLEND);
    glDepthMask(GL_FALSE);
    /* 3. the outer surface, translucent, the removed half clipped */
    glDepthFunc(GL_LESS);
    glUniform1f(r->u_alpha, 1.0f);
    glUniform1i(r->u_clip, 1);
    draw_buf(r, &s->glass, GL_TRIANGLES);
    glDepthMask(GL_TRUE);
    glDisable(GL_BLEND);
    GLenum e = glGetError();
    if (e != GL_NO_ERROR) {
        ns_set_err(err, err_sz, "OpenGL error 0x%04x while drawing the %s view", e, s->label);
        return -1;
    }
    return 0;
}

void ns_renderer_flush(NsRenderer *r)
{
    glFlush();
    (void)r;
}

int ns_renderer_read(NsRenderer *r, NsImage *im, int x, int w, char *err, int err_sz)
{
    glDisable(GL_SCISSOR_TEST);
    glBindFramebuffer(GL_READ_FRAMEBUFFER, r->fbo_ms);
    if (r->samples > 1) {
        glBindFramebuffer(GL_DRAW_FRAMEBUFFER, r->fbo_rs);
        glBlitFramebuffer(x, 0, x + w, r->h, x, 0, x + w, r->h, GL_COLOR_BUFFER_BIT, GL_NEAREST);
        glBindFramebuffer(GL_READ_FRAMEBUFFER, r->fbo_rs);
    }
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    glReadPixels(x, 0, w, r->h, GL_RGBA, GL_UNSIGNED_BYTE, r->rgba);
    glBindFramebuffer(GL_FRAMEBUFFER, r->fbo_ms);
    GLenum e = glGetError();
    if (e != GL_NO_ERROR) {
        ns_set_err(err, err_sz, "OpenGL error 0x%04x reading the frame back", e);
        return -1;
    }
    if ((im->w != r->w || im->h != r->h) || !im->rgb) {
        ns_image_free(im);
        if (ns_image_alloc(im, r->w, r->h, err, err_sz))
            return -1;
        memset(im->rgb, 0, (size_t)r->w * r->h * 3);
    }
    for (int yy = 0; yy < r->h; yy++) { /* GL's rows run bottom-up */
        const uint8_t *src = r->rgba + (size_t)(r->h - 1 - yy) * w * 4;
        uint8_t *dst = im->rgb + ((size_t)yy * r->w + x) * 3;
        for (int xx = 0; xx < w; xx++) {
            dst[3 * xx] = src[4 * xx];
            dst[3 * xx + 1] = src[4 * xx + 1];
            dst[3 * xx + 2] = src[4 * xx + 2];
        }
    }
    return 0;
}
