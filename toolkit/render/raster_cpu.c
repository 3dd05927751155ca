/* The training rasterizer's forward and backward in plain C (toolkit/render/rasterize.py, _NativeRaster).

Same semantics and precision as the torch path (_Raster; docs/design.md, "Renderer semantics"):
per (tile, Gaussian) pair, u0 = a dx + b dy and v0 = c dy at the tile centre in float64, rounded to
float32; per pixel in float32, U = (u0 + a L_col) + b L_row, v = v0 + c L_row,
exponent = (log o - v^2) - U^2, alpha = min(0.99, exp(exponent)), skipped below 1/255;
next_T = T (1 - alpha), and the pixel stops, that Gaussian excluded, when next_T <= 1e-4.
A pixel sees a Gaussian only inside its closed radius box, |float32(d) + L| <= float32(radius).
T is a sequential float32 product (the torch path rounds a cumulative product taken in float64, so T
may differ by a few ulps, never at the exact stop tie of two capped alphas); the colour sums are
float32. The backward recovers T before each Gaussian as T / (1 - alpha), as gsplat's does, and sums
each pair's gradient over its pixels in float64.

Layout: gq [M, 10] float64 rows (mean2d x, y, a, b, c, log o, r, g, b, z); radii [M, 2] float64;
pair_gauss [P] int64 by tile, front to back; tile_start, tile_count [T] int64; per tile, pixel
q = row * s + column. Each call renders the tiles t0..t1-1; the caller runs disjoint ranges on its own threads
(each tile's pairs and pixels belong to one call), then sums the pairs' gradient rows per Gaussian.
Compile without FMA contraction and fast-math: the rounding follows the source. */

#include <math.h>
#include <stdint.h>

#define MAX_S 64                          /* the largest tile side rasterize accepts */
#define NQ 10                             /* columns of gq and of the per-pair gradient */
#define ALPHA_MIN ((float)(1.0 / 255.0))  /* skip alpha below this */
#define MAX_ALPHA ((float)0.99)           /* alpha cap */
#define T_MIN ((float)1e-4)               /* stop when next_T <= this */
/* exp(x) < 1/255 for x < -5.6 (ln(1/255) = -5.54): those alphas are skipped without evaluating exp,
   and the torch path's floor of the exponent at -60 never binds above it. */
#define SKIP_EXPONENT (-5.6f)

typedef struct {
    const double *gq, *radii;
    const int64_t *pair_gauss, *tile_start, *tile_count;
    int64_t tiles_x, s, width, height;
    float L[MAX_S]; /* offset of pixel row / column l from the tile centre: l - (s - 1) / 2 */
} Scene;

/* A tile: its first pixel's column and row, its centre in pixel coordinates. */
typedef struct {
    int64_t x0, y0;
    double cx, cy;
} Tile;

/* One pair's per-row and per-column terms over the rows i0..i1-1 and columns j0..j1-1 of its box. */
typedef struct {
    int i0, i1, j0, j1;
    float a, b, c, f[4]; /* float32 Cholesky factor, r, g, b, z */
    double d0, d1;       /* tile centre - mean2d */
    float colt[MAX_S];   /* u0 + a L_col */
    float rowt[MAX_S];   /* b L_row */
    float v[MAX_S];      /* v0 + c L_row */
    float hv[MAX_S];     /* log o - v^2 */
} Pair;

static void scene_init(Scene *sc, const double *gq, const double *radii, const int64_t *pair_gauss,
                       const int64_t *tile_start, const int64_t *tile_count, int64_t tiles_x, int64_t s,
                       int64_t width, int64_t height) {
    sc->gq = gq;
    sc->radii = radii;
    sc->pair_gauss = pair_gauss;
    sc->tile_start = tile_start;
    sc->tile_count = tile_count;
    sc->tiles_x = tiles_x;
    sc->s = s;
    sc->width = width;
    sc->height = height;
    for (int l = 0; l < s; l++) sc->L[l] = (float)l - 0.5f * (float)(s - 1);
}

static Tile tile_at(const Scene *sc, int64_t t) {
    Tile tl = {(t % sc->tiles_x) * sc->s, (t / sc->tiles_x) * sc->s, 0.0, 0.0};
    tl.cx = (double)tl.x0 + 0.5 * (double)sc->s;
    tl.cy = (double)tl.y0 + 0.5 * (double)sc->s;
    return tl;
}

/* The range lo..hi-1 of pixel offsets L inside the closed box |float32(d) + L| <= r (contiguous:
   float32(d) + L is monotone in L). */
static void box_range(const Scene *sc, double d, double r, int *lo, int *hi) {
    float d32 = (float)d, r32 = (float)r;
    int l = 0;
    while (l < sc->s && fabsf(d32 + sc->L[l]) > r32) l++;
    *lo = l;
    while (l < sc->s && !(fabsf(d32 + sc->L[l]) > r32)) l++;
    *hi = l;
}

/* The rows of gq and radii are read in list order, which jumps through memory: fetch the next early. */
static inline void prefetch_gauss(const Scene *sc, int64_t g) {
    __builtin_prefetch(sc->gq + g * NQ);
    __builtin_prefetch(sc->gq + g * NQ + NQ - 1);
    __builtin_prefetch(sc->radii + g * 2);
}

/* Fills p for Gaussian g in tile tl; returns 0 when its box holds none of the tile's pixel centres. */
static int pair_init(const Scene *sc, const Tile *tl, int64_t g, Pair *p) {
    const double *q = sc->gq + g * NQ;
    const double *r = sc->radii + g * 2;
    p->d0 = tl->cx - q[0];
    p->d1 = tl->cy - q[1];
    box_range(sc, p->d0, r[0], &p->j0, &p->j1);
    box_range(sc, p->d1, r[1], &p->i0, &p->i1);
    if (p->j0 >= p->j1 || p->i0 >= p->i1) return 0;
    float u0 = (float)(q[2] * p->d0 + q[3] * p->d1);
    float v0 = (float)(q[4] * p->d1);
    float lno = (float)q[5];
    p->a = (float)q[2];
    p->b = (float)q[3];
    p->c = (float)q[4];
    for (int k = 0; k < 4; k++) p->f[k] = (float)q[6 + k];
    for (int j = p->j0; j < p->j1; j++) p->colt[j] = u0 + p->a * sc->L[j];
    for (int i = p->i0; i < p->i1; i++) {
        p->rowt[i] = p->b * sc->L[i];
        p->v[i] = v0 + p->c * sc->L[i];
        p->hv[i] = lno - p->v[i] * p->v[i];
    }
    return 1;
}

/* alpha of the pair at pixel (i, j), 0 when skipped; *U receives u there. */
static inline float pixel_alpha(const Pair *p, int i, int j, float *U) {
    float u = p->colt[j] + p->rowt[i];
    float e = p->hv[i] - u * u;
    *U = u;
    if (e < SKIP_EXPONENT) return 0.0f;
    float alpha = expf(e);
    if (alpha < ALPHA_MIN) return 0.0f;
    return alpha < MAX_ALPHA ? alpha : MAX_ALPHA;
}

/* Pixels of tile t inside the image start alive (last = -1); the others are done (last = 0, T = 1). */
static int tile_start_pixels(const Scene *sc, const Tile *tl, float *T, int32_t *last) {
    int64_t s = sc->s;
    int n_alive = 0;
    for (int i = 0; i < s; i++)
        for (int j = 0; j < s; j++) {
            int inside = tl->y0 + i < sc->height && tl->x0 + j < sc->width;
            T[i * s + j] = 1.0f;
            last[i * s + j] = inside ? -1 : 0;
            n_alive += inside;
        }
    return n_alive;
}

/* Front to back over tile t's list: color [4, s^2] (sum w rgb, sum w z), T [s^2] after the last
   included Gaussian, last [s^2] the list position where each pixel stopped (the list length if never). */
static void forward_tile(const Scene *sc, int64_t t, float *color, float *T, int32_t *last) {
    int64_t ss = sc->s * sc->s, start = sc->tile_start[t], count = sc->tile_count[t];
    Tile tl = tile_at(sc, t);
    int n_alive = tile_start_pixels(sc, &tl, T, last);
    for (int64_t q = 0; q < 4 * ss; q++) color[q] = 0.0f;
    Pair p;
    for (int64_t k = 0; k < count && n_alive > 0; k++) {
        if (k + 1 < count) prefetch_gauss(sc, sc->pair_gauss[start + k + 1]);
        if (!pair_init(sc, &tl, sc->pair_gauss[start + k], &p)) continue;
        for (int i = p.i0; i < p.i1; i++)
            for (int j = p.j0; j < p.j1; j++) {
                int64_t q = i * sc->s + j;
                float U, alpha;
                if (last[q] >= 0 || (alpha = pixel_alpha(&p, i, j, &U)) == 0.0f) continue;
                float next_T = T[q] * (1.0f - alpha);
                if (next_T <= T_MIN) {
                    last[q] = (int32_t)k;
                    n_alive--;
                    continue;
                }
                float w = alpha * T[q];
                for (int c = 0; c < 4; c++) color[c * ss + q] += w * p.f[c];
                T[q] = next_T;
            }
    }
    for (int64_t q = 0; q < ss; q++)
        if (last[q] < 0) last[q] = (int32_t)count;
}

int raster_forward(const double *gq, const double *radii, const int64_t *pair_gauss, const int64_t *tile_start,
                   const int64_t *tile_count, int64_t tiles_x, int64_t s, int64_t width, int64_t height, int64_t t0,
                   int64_t t1, float *color, float *T_final, int32_t *last) {
    if (s < 1 || s > MAX_S) return 1;
    Scene sc;
    scene_init(&sc, gq, radii, pair_gauss, tile_start, tile_count, tiles_x, s, width, height);
    int64_t ss = s * s;
    for (int64_t t = t0; t < t1; t++) forward_tile(&sc, t, color + t * 4 * ss, T_final + t * ss, last + t * ss);
    return 0;
}

/* Per-pair sums of the gradient of the exponent's inputs over the pixels, in float64. */
typedef struct {
    double u0, aL, bL, v0, cL, lno, f[4];
} PairGrad;

static void zero_row(double *row) {
    for (int c = 0; c < NQ; c++) row[c] = 0.0;
}

/* The gradient row of pair p from its sums: mean2d x, y, a, b, c, log o, r, g, b, z (d = centre - mean2d). */
static void pair_grad_row(const Pair *p, const PairGrad *s, double *out) {
    out[0] = -s->u0 * (double)p->a;
    out[1] = -s->u0 * (double)p->b - s->v0 * (double)p->c;
    out[2] = s->aL + s->u0 * p->d0;
    out[3] = s->bL + s->u0 * p->d1;
    out[4] = s->cL + s->v0 * p->d1;
    out[5] = s->lno;
    for (int c = 0; c < 4; c++) out[6 + c] = s->f[c];
}

/* Back to front over tile t's list (gsplat's backward): T before each Gaussian is recovered as
   T / (1 - alpha); S is the sum over later Gaussians of w dL/dw plus T_final dL/dT_final. Writes the
   gradient rows of the pairs whose box meets the tile. */
static void backward_tile(const Scene *sc, int64_t t, const float *T_final, const int32_t *last,
                          const float *g_color, const float *g_T, double *g_pair) {
    int64_t s = sc->s, ss = s * s, start = sc->tile_start[t], count = sc->tile_count[t];
    float T[MAX_S * MAX_S], S[MAX_S * MAX_S];
    Tile tl = tile_at(sc, t);
    int32_t k_end = 0;
    for (int64_t q = 0; q < ss; q++) {
        T[q] = T_final[q];
        S[q] = T_final[q] * g_T[q];
        if (last[q] > k_end) k_end = last[q];
    }
    for (int64_t k = k_end; k < count; k++) zero_row(g_pair + (start + k) * NQ);
    Pair p;
    for (int64_t k = (int64_t)k_end - 1; k >= 0; k--) {
        if (k > 0) prefetch_gauss(sc, sc->pair_gauss[start + k - 1]);
        if (!pair_init(sc, &tl, sc->pair_gauss[start + k], &p)) {
            zero_row(g_pair + (start + k) * NQ);
            continue;
        }
        PairGrad acc = {0};
        for (int i = p.i0; i < p.i1; i++)
            for (int j = p.j0; j < p.j1; j++) {
                int64_t q = i * s + j;
                float U, alpha;
                if (k >= last[q] || (alpha = pixel_alpha(&p, i, j, &U)) == 0.0f) continue;
                float onem = 1.0f - alpha;
                float T_k = T[q] / onem;
                float w = alpha * T_k;
                float e = 0.0f; /* dL/dw */
                for (int c = 0; c < 4; c++) {
                    e += g_color[c * ss + q] * p.f[c];
                    acc.f[c] += g_color[c * ss + q] * w;
                }
                /* dL/dalpha, then dL/d exponent: alpha where alpha is not capped */
                float g = e * T_k - S[q] / onem;
                g = alpha < MAX_ALPHA ? g * alpha : 0.0f;
                S[q] += w * e;
                T[q] = T_k;
                float gu = -2.0f * U * g, gv = -2.0f * p.v[i] * g;
                acc.u0 += gu;
                acc.aL += (double)gu * sc->L[j];
                acc.bL += (double)gu * sc->L[i];
                acc.v0 += gv;
                acc.cL += (double)gv * sc->L[i];
                acc.lno += g;
            }
        pair_grad_row(&p, &acc, g_pair + (start + k) * NQ);
    }
}

int raster_backward(const double *gq, const double *radii, const int64_t *pair_gauss, const int64_t *tile_start,
                    const int64_t *tile_count, int64_t tiles_x, int64_t s, int64_t width, int64_t height, int64_t t0,
                    int64_t t1, const float *T_final, const int32_t *last, const float *g_color, const float *g_T,
                    double *g_pair) {
    if (s < 1 || s > MAX_S) return 1;
    Scene sc;
    scene_init(&sc, gq, radii, pair_gauss, tile_start, tile_count, tiles_x, s, width, height);
    int64_t ss = s * s;
    for (int64_t t = t0; t < t1; t++)
        backward_tile(&sc, t, T_final + t * ss, last + t * ss, g_color + t * 4 * ss, g_T + t * ss, g_pair);
    return 0;
}

/* g_gq [M, 10] += per Gaussian, the sum of its pairs' rows g_pair [P, 10], in pair order. */
int raster_sum_pairs(const int64_t *pair_gauss, int64_t n_pairs, const double *g_pair, double *g_gq) {
    for (int64_t i = 0; i < n_pairs; i++)
        for (int c = 0; c < NQ; c++) g_gq[pair_gauss[i] * NQ + c] += g_pair[i * NQ + c];
    return 0;
}
