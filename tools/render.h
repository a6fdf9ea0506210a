/* The renderer of `rtktool trace` and of the benchmark's path tracer: eye
 * light, normals, ambient occlusion and a diffuse-only path tracer, over
 * threads, through single rays or packets of 4, 8 or 16.
 *
 * It reaches the ray tracer only through a table of functions
 * (render_tracer), so the same renderer code drives rtk and, in `rtktool
 * bench`, Embree: what differs between the two measurements is the ray
 * tracer and nothing else.
 *
 * Images do not depend on the thread count or on the API: every path draws
 * its random numbers from a generator seeded by its pixel and sample alone,
 * and shades its hits with the same code whether its rays went one by one or
 * in a packet.  (They can differ where two triangles are hit at exactly the
 * same distance and the two calls pick different ones.) */
#ifndef RTK_TOOLS_RENDER_H
#define RTK_TOOLS_RENDER_H

#include <stddef.h>
#include <stdint.h>

#include "rtk/rtk.h"

typedef enum render_mode {
    RENDER_EYELIGHT, /* brightness by the angle between the surface and the view */
    RENDER_NORMALS,  /* the geometric normal (as the triangle's winding gives it) as a colour */
    RENDER_AO,       /* ambient occlusion: the share of short rays from the hit that escape */
    RENDER_DIFFUSE,  /* path tracer: grey diffuse surfaces under a sky and a sun */
} render_mode;

/* "eyelight", ...; NULL for an unknown mode. */
const char *render_mode_name(render_mode mode);
int render_mode_parse(const char *name, render_mode *mode);

/* The ray-tracing calls a render uses: 1 (intersect1/occluded1), the
 * packet width 4, 8, 16, or RENDER_API_STREAM (intersect1M/occluded1M).
 * "single", "packet4", "packet8", "packet16", "stream"; render_api_parse
 * gives 0 for anything else. */
#define RENDER_API_STREAM 1024
const char *render_api_name(int api);
int render_api_parse(const char *name);

/* A direction about the unit normal n, cosine-weighted (density cos / pi),
 * from two uniform numbers in [0, 1): a point of the unit disk (radius
 * sqrt(u1), angle 2 pi u2) lifted onto the hemisphere. */
void render_cosine_dir(const float n[3], float u1, float u2, float out[3]);

/* Pinhole camera: the ray through pixel position (x, y) (in pixels, from the
 * top-left corner) leaves eye in the direction corner + x * du + y * dv. */
typedef struct render_camera {
    float eye[3], target[3], up[3], fov; /* what it was made from; fov vertical, degrees */
    float du[3], dv[3], corner[3];
} render_camera;

/* A camera at eye looking at target, with up roughly up and a vertical field
 * of view of fov degrees, for a w x h image; non-zero (with a message) when
 * the numbers make no camera: non-finite, eye == target, up along the view,
 * fov outside (0, 180). */
int render_camera_look(render_camera *cam, const float eye[3], const float target[3], const float up[3], float fov,
                       int w, int h, char *err, size_t err_size);
/* A camera that frames a bounding box: looking at its centre from the
 * front-right and above, 40-degree view, just far enough for all eight
 * corners to fit with a 5% margin. */
void render_camera_frame(render_camera *cam, const float lower[3], const float upper[3], int w, int h);
/* Parses --camera's "EX,EY,EZ/TX,TY,TZ[/UX,UY,UZ[/FOV]]" (up defaults to
 * 0,1,0 and fov to 40); non-zero with a message when it is malformed. */
int render_camera_parse(render_camera *cam, const char *spec, int w, int h, char *err, size_t err_size);

/* The ray tracer, as the renderer calls it.  The ray and hit structures are
 * rtk's; Embree's have the same layout (rtktool bench checks). */
typedef struct render_tracer {
    void *scene;
    void (*intersect1)(void *scene, rtk_rayhit *rayhit);
    void (*occluded1)(void *scene, rtk_ray *ray);
    void (*intersect4)(void *scene, const int *valid, rtk_rayhit4 *rayhit);
    void (*occluded4)(void *scene, const int *valid, rtk_ray4 *ray);
    void (*intersect8)(void *scene, const int *valid, rtk_rayhit8 *rayhit);
    void (*occluded8)(void *scene, const int *valid, rtk_ray8 *ray);
    void (*intersect16)(void *scene, const int *valid, rtk_rayhit16 *rayhit);
    void (*occluded16)(void *scene, const int *valid, rtk_ray16 *ray);
    /* streams: n rays `stride` bytes apart */
    void (*intersect1M)(void *scene, rtk_rayhit *rayhits, unsigned n, size_t stride);
    void (*occluded1M)(void *scene, rtk_ray *rays, unsigned n, size_t stride);
} render_tracer;

/* n = 1, 4, 8 or 16 rays through the tracer's call of that width, for the
 * lanes with valid[k] != 0: closest hits (rh[k] in, tfar and hit out, as
 * rtk_intersect1 writes them) or, when occluded, any hits (rh[k].ray.tfar
 * becomes -inf).  valid must be aligned to 4 * n bytes, as Embree requires
 * of its masks.  Packets are loaded from and stored to rh here, as an
 * application would, so this costs both ray tracers the same.  (Streams:
 * the tracer's intersect1M / occluded1M on rh directly.) */
void render_trace(const render_tracer *t, int n, const int *valid, rtk_rayhit *rh, int occluded);

/* The table for an rtk scene. */
render_tracer render_tracer_rtk(rtk_scene scene);

typedef struct render_settings {
    int width, height;
    int spp;           /* samples per pixel (jittered when more than 1) */
    render_mode mode;
    int api;           /* 1: intersect1/occluded1; 4, 8, 16: packets of 2x2, 4x2, 4x4 pixels;
                        * RENDER_API_STREAM: wavefront, each bounce's rays of a tile one stream */
    int threads;
    int max_bounces;   /* diffuse: surface hits per path at most */
    int rr_depth;      /* diffuse: Russian roulette from this bounce on */
    int ao_samples;    /* ao: rays per hit */
    float ao_distance; /* ao: their length */
    float eps;         /* offset of secondary rays from the surface */
    float albedo[3];
    float sky_zenith[3], sky_horizon[3]; /* sky radiance, straight up and at the horizon */
    float ground[3];                     /* radiance from below the horizon */
    float up[3];                         /* the sky's up (normalised by the renderer) */
    float sun_dir[3];                    /* towards the sun (normalised by the renderer) */
    float sun[3];                        /* the sun's irradiance on a surface facing it */
    float background[3];                 /* eyelight, normals, ao: where the camera rays miss */
    uint32_t seed;
    render_camera camera;
    /* Called on the calling thread about ten times a second with the share
     * of the image done (0..1); NULL for none. */
    void (*progress)(void *user, double done);
    void *progress_user;
} render_settings;

/* Defaults for a scene with these bounds and a w x h image: eye light, one
 * sample, single rays, one thread, the framing camera, a sky from above
 * (up 0,1,0) and a sun from above the camera's right shoulder, AO rays a
 * tenth of the scene's size, eps a millionth of its farthest coordinate. */
void render_defaults(render_settings *s, const float lower[3], const float upper[3], int w, int h);

typedef struct render_stats {
    uint64_t primary, primary_hits; /* camera rays and those that hit */
    uint64_t bounce;                /* diffuse: closest-hit rays after the first hit */
    uint64_t shadow;                /* diffuse: any-hit rays towards the sun */
    uint64_t ao;                    /* ao: any-hit rays */
    double seconds;                 /* wall clock of the whole image */
} render_stats;

uint64_t render_stats_rays(const render_stats *st);

/* Renders into rgb (width * height * 3 floats, linear radiance for diffuse,
 * display values otherwise, rows from the top); 0, or non-zero with a
 * message for settings it cannot render (the tracer lacking a function the
 * API needs, sizes out of range, no memory or threads). */
int render_image(const render_tracer *tracer, const render_settings *s, float *rgb, render_stats *stats, char *err,
                 size_t err_size);

/* 8-bit sRGB for a PNG: diffuse through the sRGB curve, the other modes
 * as they are; clamped. */
void render_to_rgb8(const render_settings *s, const float *rgb, unsigned char *out);

#endif
