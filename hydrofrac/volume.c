/* The volume terms and the inverse mass of the matrix-free DG operator, in blocks of W cells
 * (hydrofrac/native.py compiles it with NB, the basis functions per cell, as a constant).
 *
 * It computes what the numba kernel volume_and_inverse in hydrofrac/matfree.py computes for a
 * cell-contiguous DG space (cell c's values at X[5 NB c .. 5 NB (c+1)), node-major, 5 fields per
 * node):  out[c] = M_c^{-1} (R[c] + volume terms of X[c]),  and R[c] = 0 after.
 *
 * The difference is the loop order.  The numba kernel works cell by cell; its loops over 5
 * fields and NB nodes are unrolled but scalar.  Here the W cells of a block sit in the innermost
 * loop index ("lanes"), so every multiply-add of the dense reference products (S_r u,
 * Minv_ref r) is one vector operation over W cells.  W = 4 (one 256-bit vector of doubles)
 * measured fastest here against W = 2, 8 and 16 (docs/benchmarks.md, "Volume kernels in C").
 * Each lane does the same arithmetic as the numba kernel in the same order; the two agree to
 * round-off (tests/test_matfree.py).
 */
#ifndef NB
#error "compile with -DNB=<basis functions per cell>"
#endif
#ifndef W
#define W 4
#endif
/* at P1 (NB = 3) the gradients are constant: one row of S_r serves every node */
#define ROWS (NB == 3 ? 1 : NB)

/* A block's cell data: the values u (NB nodes, 5 fields, W lanes), and per lane the inverse
 * Jacobian (row by row) and 1/|det J| in jac[0..4].  A short last block repeats its first cell in
 * the empty lanes (computed, never stored). */
static inline void load_block(double u[NB][5][W], double jac[5][W], const double *restrict X,
                              const double *restrict Jinv, const double *restrict invdet, long c0, long w)
{
    for (long l = 0; l < W; l++) {
        const long c = c0 + (l < w ? l : 0);
        for (int j = 0; j < NB; j++)
            for (int k = 0; k < 5; k++) u[j][k][l] = X[5 * (NB * c + j) + k];
        for (int q = 0; q < 4; q++) jac[q][l] = Jinv[4 * c + q];
        jac[4][l] = invdet[c];
    }
}

/* Reference derivatives g_r = A_r u of nin rows of values into nout rows: the dense products of
 * every kernel (S_r, and the links of ADER's predictor chain). */
static inline void products(double g0[][5][W], double g1[][5][W], const double *restrict A0,
                            const double *restrict A1, double u[][5][W], int nout, int nin)
{
    for (int i = 0; i < nout; i++)
        for (int k = 0; k < 5; k++) {
            double s0[W] = {0}, s1[W] = {0};
            for (int j = 0; j < nin; j++) {
                const double a = A0[i * nin + j], b = A1[i * nin + j];
                for (int l = 0; l < W; l++) {
                    s0[l] += a * u[j][k][l];
                    s1[l] += b * u[j][k][l];
                }
            }
            for (int l = 0; l < W; l++) {
                g0[i][k][l] = s0[l];
                g1[i][k][l] = s1[l];
            }
        }
}

/* The volume terms' reference derivatives g_r = S_r u (ROWS rows: one at P1). */
static inline void derivatives(double g0[ROWS][5][W], double g1[ROWS][5][W], const double *restrict A0,
                               const double *restrict A1, double u[NB][5][W])
{
    products(g0, g1, A0, A1, u, ROWS, NB);
}

void volume_and_inverse(double *restrict out, double *restrict R, const double *restrict X, long ncells,
                        const double *restrict S0, const double *restrict S1, const double *restrict Jinv,
                        const double *restrict invdet, const double *restrict Minv, const int *restrict mat,
                        const double *restrict Btab)
{
    for (long c0 = 0; c0 < ncells; c0 += W) {
        const long w = ncells - c0 < W ? ncells - c0 : W;  /* cells in this block */
        double u[NB][5][W], g0[ROWS][5][W], g1[ROWS][5][W], r[NB][5][W], jac[5][W];
        load_block(u, jac, X, Jinv, invdet, c0, w);
        const double *j00 = jac[0], *j01 = jac[1], *j10 = jac[2], *j11 = jac[3], *e = jac[4];
        derivatives(g0, g1, S0, S1, u);
        /* r = R / |det J| + volume terms (d/dx = Jinv[0,0] d/dX0 + Jinv[1,0] d/dX1, ...) */
        for (int i = 0; i < NB; i++) {
            const int iv = ROWS == NB ? i : 0;
            for (long l = 0; l < W; l++) {
                const long c = c0 + (l < w ? l : 0);
                const double *Rc = R + 5 * (NB * c + i);
                const double dx_vx = j00[l] * g0[iv][0][l] + j10[l] * g1[iv][0][l];
                const double dy_vx = j01[l] * g0[iv][0][l] + j11[l] * g1[iv][0][l];
                const double dx_vy = j00[l] * g0[iv][1][l] + j10[l] * g1[iv][1][l];
                const double dy_vy = j01[l] * g0[iv][1][l] + j11[l] * g1[iv][1][l];
                const double dx_sxx = j00[l] * g0[iv][2][l] + j10[l] * g1[iv][2][l];
                const double dy_syy = j01[l] * g0[iv][3][l] + j11[l] * g1[iv][3][l];
                const double dx_sxy = j00[l] * g0[iv][4][l] + j10[l] * g1[iv][4][l];
                const double dy_sxy = j01[l] * g0[iv][4][l] + j11[l] * g1[iv][4][l];
                r[i][0][l] = e[l] * Rc[0] + (dx_sxx + dy_sxy);
                r[i][1][l] = e[l] * Rc[1] + (dx_sxy + dy_syy);
                r[i][2][l] = e[l] * Rc[2] + dx_vx;
                r[i][3][l] = e[l] * Rc[3] + dy_vy;
                r[i][4][l] = e[l] * Rc[4] + (dy_vx + dx_vy);
            }
        }
        /* cleared for the next stage (saves a separate pass) */
        for (long m = 5 * NB * c0; m < 5 * NB * (c0 + w); m++) R[m] = 0.0;
        /* M_c^{-1} = Minv_ref kron B^{-1} / |det J| (the 1/|det J| is in r already) */
        for (int a = 0; a < NB; a++) {
            double t[5][W];
            for (int k = 0; k < 5; k++) {
                double acc[W] = {0};
                for (int b = 0; b < NB; b++) {
                    const double m = Minv[a * NB + b];
                    for (int l = 0; l < W; l++) acc[l] += m * r[b][k][l];
                }
                for (int l = 0; l < W; l++) t[k][l] = acc[l];
            }
            for (long l = 0; l < w; l++) {
                const double *B = Btab + 11 * mat[c0 + l];  /* 1/rho, 1/rho, the 3x3 stiffness block */
                double *o = out + 5 * (NB * (c0 + l) + a);
                o[0] = B[0] * t[0][l];
                o[1] = B[1] * t[1][l];
                o[2] = B[2] * t[2][l] + B[3] * t[3][l] + B[4] * t[4][l];
                o[3] = B[5] * t[2][l] + B[6] * t[3][l] + B[7] * t[4][l];
                o[4] = B[8] * t[2][l] + B[9] * t[3][l] + B[10] * t[4][l];
            }
        }
    }
}

/* The interior facets' upwind flux corrections, in blocks of W facets: what the numba kernel
 * facet_fluxes in hydrofrac/matfree.py computes for a cell-contiguous space.  NK = nodes per
 * facet (p + 1).
 *
 * The bonded Riemann solution is linear in the jumps [v] = v- - v+ and [s] = s- - s+ of each
 * component, with coefficients that depend on the two sides' impedances only.  Those come from
 * hydrofrac.riemann.bonded_jump_pt (the one place of the formula), evaluated once per distinct
 * impedance pair on unit jumps: coef[pair[f]] holds, for the normal then the tangential
 * component, the coefficients of [v] in (s_B - s+, v_B - v+, s_B - s-, v_B - v-), then those
 * of [s].  The scatter into R runs lane by lane (two facets of a block may share a cell).
 */
#ifdef NK
void facet_fluxes(double *restrict R, const double *restrict X, long nfacets, const long *restrict fcells,
                  const long *restrict fcodes, const double *restrict normal, const double *restrict length,
                  const long *restrict fnodes, const double *restrict Mf, const double *restrict coef,
                  const int *restrict pair, long nowned)
{
    for (long f0 = 0; f0 < nfacets; f0 += W) {
        const long w = nfacets - f0 < W ? nfacets - f0 : W;
        double Fp[NK][5][W], Fm[NK][5][W], Gp[NK][5][W], Gm[NK][5][W];
        for (int k = 0; k < NK; k++) {
            for (long l = 0; l < W; l++) {
                const long f = f0 + (l < w ? l : 0);
                const long cp = fcells[2 * f], cm = fcells[2 * f + 1];
                const double *xp = X + 5 * (NB * cp + fnodes[NK * fcodes[2 * f] + k]);
                const double *xm = X + 5 * (NB * cm + fnodes[NK * fcodes[2 * f + 1] + k]);
                const double nx = normal[2 * f], ny = normal[2 * f + 1];
                const double *cf = coef + 16 * pair[f];
                /* the jumps in the facet frame (n, t = (-ny, nx)), as _node_jumps */
                const double j0 = xm[0] - xp[0], j1 = xm[1] - xp[1], j2 = xm[2] - xp[2], j3 = xm[3] - xp[3],
                             j4 = xm[4] - xp[4];
                const double tx = j2 * nx + j4 * ny, ty = j4 * nx + j3 * ny;
                const double jvn = j0 * nx + j1 * ny, jvt = -j0 * ny + j1 * nx;
                const double jsn = tx * nx + ty * ny, jst = -tx * ny + ty * nx;
                const double dspn = cf[0] * jvn + cf[4] * jsn, dvpn = cf[1] * jvn + cf[5] * jsn;
                const double dsmn = cf[2] * jvn + cf[6] * jsn, dvmn = cf[3] * jvn + cf[7] * jsn;
                const double dspt = cf[8] * jvt + cf[12] * jst, dvpt = cf[9] * jvt + cf[13] * jst;
                const double dsmt = cf[10] * jvt + cf[14] * jst, dvmt = cf[11] * jvt + cf[15] * jst;
                /* side +: outward normal n */
                double dsx = dspn * nx - dspt * ny, dsy = dspn * ny + dspt * nx;
                double dvx = dvpn * nx - dvpt * ny, dvy = dvpn * ny + dvpt * nx;
                Fp[k][0][l] = dsx;
                Fp[k][1][l] = dsy;
                Fp[k][2][l] = dvx * nx;
                Fp[k][3][l] = dvy * ny;
                Fp[k][4][l] = dvx * ny + dvy * nx;
                /* side -: outward normal -n and traction -s*, so both terms change sign */
                dsx = -(dsmn * nx - dsmt * ny);
                dsy = -(dsmn * ny + dsmt * nx);
                dvx = -(dvmn * nx - dvmt * ny);
                dvy = -(dvmn * ny + dvmt * nx);
                Fm[k][0][l] = dsx;
                Fm[k][1][l] = dsy;
                Fm[k][2][l] = dvx * nx;
                Fm[k][3][l] = dvy * ny;
                Fm[k][4][l] = dvx * ny + dvy * nx;
            }
        }
        /* the facet mass matrix, times the length */
        for (int i = 0; i < NK; i++)
            for (int m = 0; m < 5; m++) {
                double ap[W] = {0}, am[W] = {0};
                for (int k = 0; k < NK; k++) {
                    const double mf = Mf[i * NK + k];
                    for (int l = 0; l < W; l++) {
                        ap[l] += mf * Fp[k][m][l];
                        am[l] += mf * Fm[k][m][l];
                    }
                }
                for (int l = 0; l < W; l++) {
                    Gp[i][m][l] = ap[l];
                    Gm[i][m][l] = am[l];
                }
            }
        for (long l = 0; l < w; l++) {
            const long f = f0 + l;
            const long cp = fcells[2 * f], cm = fcells[2 * f + 1];
            const double L = length[f];
            if (cp < nowned)
                for (int i = 0; i < NK; i++) {
                    double *r = R + 5 * (NB * cp + fnodes[NK * fcodes[2 * f] + i]);
                    for (int m = 0; m < 5; m++) r[m] += L * Gp[i][m][l];
                }
            if (cm < nowned)
                for (int i = 0; i < NK; i++) {
                    double *r = R + 5 * (NB * cm + fnodes[NK * fcodes[2 * f + 1] + i]);
                    for (int m = 0; m < 5; m++) r[m] += L * Gm[i][m][l];
                }
        }
    }
}
#endif

/* The rate of energy the upwind flux dissipates on the owned listed facets, in blocks of W facets:
 * what the numba kernel facet_dissipation in hydrofrac/matfree.py computes for a cell-contiguous
 * space, int sum_i a_i [[v_i]]^2 + c_i [[s_i]]^2 (i = n, t; a_i = Z_i+ Z_i- / (Z_i+ + Z_i-),
 * c_i = 1 / (Z_i+ + Z_i-)) from the jumps at the facet nodes and the facet mass matrix.  dcoef
 * (pairs, 4) holds a_n, a_t, c_n, c_t per impedance pair; own[f] = 0 leaves a facet out (a
 * ghost's, counted by its owner).  Lanes are summed at the end. */
#ifdef NK
double facet_dissipation(const double *restrict X, long nfacets, const long *restrict fcells,
                         const long *restrict fcodes, const double *restrict normal,
                         const double *restrict length, const long *restrict fnodes, const double *restrict Mf,
                         const double *restrict dcoef, const int *restrict pair, const unsigned char *restrict own)
{
    double total[W] = {0};
    for (long f0 = 0; f0 < nfacets; f0 += W) {
        const long w = nfacets - f0 < W ? nfacets - f0 : W;
        double J[NK][4][W], wt[W], cf[4][W];
        for (long l = 0; l < W; l++) {
            const long f = f0 + (l < w ? l : 0);
            wt[l] = (l < w && own[f]) ? length[f] : 0.0;
            for (int q = 0; q < 4; q++) cf[q][l] = dcoef[4 * pair[f] + q];
            const long cp = fcells[2 * f], cm = fcells[2 * f + 1];
            const double nx = normal[2 * f], ny = normal[2 * f + 1];
            for (int k = 0; k < NK; k++) {
                const double *xp = X + 5 * (NB * cp + fnodes[NK * fcodes[2 * f] + k]);
                const double *xm = X + 5 * (NB * cm + fnodes[NK * fcodes[2 * f + 1] + k]);
                const double j0 = xm[0] - xp[0], j1 = xm[1] - xp[1], j2 = xm[2] - xp[2], j3 = xm[3] - xp[3],
                             j4 = xm[4] - xp[4];
                const double tx = j2 * nx + j4 * ny, ty = j4 * nx + j3 * ny;
                J[k][0][l] = j0 * nx + j1 * ny;
                J[k][1][l] = -j0 * ny + j1 * nx;
                J[k][2][l] = tx * nx + ty * ny;
                J[k][3][l] = -tx * ny + ty * nx;
            }
        }
        double acc[W] = {0};
        for (int k = 0; k < NK; k++)
            for (int m = 0; m < NK; m++) {
                const double mf = Mf[k * NK + m];
                for (long l = 0; l < W; l++)
                    acc[l] += mf * (cf[0][l] * J[k][0][l] * J[m][0][l] + cf[1][l] * J[k][1][l] * J[m][1][l]
                                    + cf[2][l] * J[k][2][l] * J[m][2][l] + cf[3][l] * J[k][3][l] * J[m][3][l]);
            }
        for (long l = 0; l < W; l++) total[l] += wt[l] * acc[l];
    }
    double t = 0.0;
    for (long l = 0; l < W; l++) t += total[l];
    return t;
}
#endif

/* The strong-form volume terms r of reference derivatives (g0, g1) on n rows: the inverse
 * Jacobian's combinations, field by field (row iv = 0 for every row where the rows are equal). */
static inline void strong_terms(double r[][5][W], double g0[][5][W], double g1[][5][W], int n, int same,
                                const double *j00, const double *j01, const double *j10, const double *j11)
{
    for (int i = 0; i < n; i++) {
        const int iv = same ? 0 : i;
        for (int l = 0; l < W; l++) {
            r[i][0][l] = j00[l] * g0[iv][2][l] + j10[l] * g1[iv][2][l] + j01[l] * g0[iv][4][l]
                         + j11[l] * g1[iv][4][l];
            r[i][1][l] = j00[l] * g0[iv][4][l] + j10[l] * g1[iv][4][l] + j01[l] * g0[iv][3][l]
                         + j11[l] * g1[iv][3][l];
            r[i][2][l] = j00[l] * g0[iv][0][l] + j10[l] * g1[iv][0][l];
            r[i][3][l] = j01[l] * g0[iv][1][l] + j11[l] * g1[iv][1][l];
            r[i][4][l] = j01[l] * g0[iv][0][l] + j11[l] * g1[iv][0][l] + j00[l] * g0[iv][1][l]
                         + j10[l] * g1[iv][1][l];
        }
    }
}

/* w = B^-1 t of one row, lane l (B^-1 = diag(1/rho, 1/rho) + the 3x3 stiffness block). */
#define BINV(wv, t, Bl, l)                                                                           \
    const double wv[5] = {Bl[0][l] * t[0][l], Bl[1][l] * t[1][l],                                    \
                          Bl[2][l] * t[2][l] + Bl[3][l] * t[3][l] + Bl[4][l] * t[4][l],              \
                          Bl[5][l] * t[2][l] + Bl[6][l] * t[3][l] + Bl[7][l] * t[4][l],              \
                          Bl[8][l] * t[2][l] + Bl[9][l] * t[3][l] + Bl[10][l] * t[4][l]}

/* dim P_k */
#define DIM(k) (((k) + 1) * ((k) + 2) / 2)
/* the degree p (NK = p + 1 nodes per facet) */
#define DEG (NK - 1)

/* One link of the predictor's chain (hydrofrac/matfree.py, taylor_chain): the reference
 * derivatives g_r (nout rows) of the values r (nin rows) with the link's matrices at *ch; moves
 * *ch past the link and returns its interpolation matrix at the nodes (NB x nout). */
static inline const double *chain_derivative(double g0[][5][W], double g1[][5][W], const double **ch,
                                             double r[][5][W], int nin, int nout)
{
    const double *A0 = *ch, *A1 = *ch + nout * nin, *V = *ch + 2 * nout * nin;
    *ch = V + NB * nout;
    products(g0, g1, A0, A1, r, nout, nin);
    return V;
}

/* ADER's corrector and next predictor, in blocks of W cells: what the numba kernel ader_corrector
 * in hydrofrac/matfree.py computes for a cell-contiguous space.  Per cell: x += M_c^{-1} (R[c] +
 * volume terms of I) (R[c] cleared), then I = sum_{k=0..order} dt^(k+1)/(k+1)! D^k x, D the
 * cell-local strong-form operator.
 *
 * The predictor works in the degrees its terms have (hydrofrac/matfree.py, taylor_chain): D^m x
 * lies in P_{p-m}, so it is held by its values on the (p-m)-lattice, n_{p-m} rows instead of
 * the NB nodes, and each term is interpolated at the nodes as it is added to I.  The numba kernel
 * takes D^m x at the nodes with D_r = Minv_ref S_r; the two agree to round-off.  At p = 3 the
 * predictor's multiply-adds fall from 3 x 1,230 to about 1,640 a cell (docs/benchmarks.md, "ADER's
 * predictor in the degrees it has"). */
void ader_corrector(double *restrict x, double *restrict I, double *restrict R, long ncells,
                    const double *restrict S0, const double *restrict S1, const double *restrict Jinv,
                    const double *restrict invdet, const double *restrict Minv, const int *restrict mat,
                    const double *restrict Btab, const double *restrict chain, double dt, long order)
{
    const long steps = order < DEG ? order : DEG; /* (D^m = 0 on P_p for m > p) */
    for (long c0 = 0; c0 < ncells; c0 += W) {
        const long w = ncells - c0 < W ? ncells - c0 : W;
        double u[NB][5][W], g0[NB][5][W], g1[NB][5][W], r[NB][5][W], acc[NB][5][W], jac[5][W], Bl[11][W];
        load_block(u, jac, I, Jinv, invdet, c0, w);
        const double *j00 = jac[0], *j01 = jac[1], *j10 = jac[2], *j11 = jac[3], *e = jac[4];
        for (long l = 0; l < W; l++) {
            const long c = c0 + (l < w ? l : 0);
            for (int q = 0; q < 11; q++) Bl[q][l] = Btab[11 * mat[c] + q];
        }
        /* the corrector: x += B^-1 M_c^-1 (R[c] + volume terms of I) */
        derivatives(g0, g1, S0, S1, u);
        strong_terms(r, g0, g1, NB, ROWS == 1, j00, j01, j10, j11);
        for (int i = 0; i < NB; i++)
            for (long l = 0; l < W; l++) {
                const long c = c0 + (l < w ? l : 0);
                for (int k = 0; k < 5; k++) r[i][k][l] += e[l] * R[5 * (NB * c + i) + k];
            }
        for (long m2 = 5 * NB * c0; m2 < 5 * NB * (c0 + w); m2++) R[m2] = 0.0;
        for (int a = 0; a < NB; a++)
            for (int k = 0; k < 5; k++) {
                double t[W] = {0};
                for (int b = 0; b < NB; b++) {
                    const double mi = Minv[a * NB + b];
                    for (int l = 0; l < W; l++) t[l] += mi * r[b][k][l];
                }
                for (int l = 0; l < W; l++) u[a][k][l] = t[l];
            }
        for (int a = 0; a < NB; a++) /* the new x; the predictor starts from it: I = dt x + ... */
            for (long l = 0; l < W; l++) {
                BINV(wv, u[a], Bl, l);
                const long c = c0 + (l < w ? l : 0);
                double *xc = x + 5 * (NB * c + a);
                for (int k = 0; k < 5; k++) {
                    const double v = xc[k] + wv[k];
                    if (l < w) xc[k] = v;
                    r[a][k][l] = v;
                    acc[a][k][l] = dt * v;
                }
            }
        /* the Taylor terms dt^(m+1)/(m+1)! D^m x, D^m x on the (p-m)-lattice in the rows of r */
        const double *ch = chain;
        double coef = dt;
        for (int m = 1; m <= DEG; m++) {
            if (m > steps) break;
            const int nin = DIM(DEG - m + 1), nout = DIM(DEG - m);
            const double *V = chain_derivative(g0, g1, &ch, r, nin, nout);
            strong_terms(u, g0, g1, nout, 0, j00, j01, j10, j11);
            coef *= dt / (double)(m + 1);
            for (int i = 0; i < nout; i++)
                for (long l = 0; l < W; l++) {
                    BINV(wv, u[i], Bl, l);
                    for (int k = 0; k < 5; k++) r[i][k][l] = wv[k];
                }
            for (int a = 0; a < NB; a++) /* I += the term, interpolated at the nodes */
                for (int k = 0; k < 5; k++) {
                    double t[W] = {0};
                    for (int i = 0; i < nout; i++) {
                        const double v = V[a * nout + i];
                        for (int l = 0; l < W; l++) t[l] += v * r[i][k][l];
                    }
                    for (int l = 0; l < W; l++) acc[a][k][l] += coef * t[l];
                }
        }
        for (long l = 0; l < w; l++)
            for (int a = 0; a < NB; a++)
                for (int k = 0; k < 5; k++) I[5 * (NB * (c0 + l) + a) + k] = acc[a][k][l];
    }
}

/* ADER's cell-local Taylor predictor on listed cells (owned or ghost), in blocks of W cells:
 * Q_i = sum_{m=0..order} tau_i^m/m! D^m x at the NT times tau_i into the step, D the cell-local
 * strong-form operator of ader_corrector (D_r, Jinv, B^-1).  Q_i is at Q + i * stride; only the
 * listed cells' blocks are written.  These are the traces the crack interfaces read inside a step
 * (hydrofrac/interface.py, Interface.ader_step).  Per cell it is the m >= 1 part of the
 * predictor above, for the listed cells only. */
#define MAXT 4
void taylor_values(double *restrict Q, long stride, const double *restrict X, long ncells,
                   const long *restrict cells, const double *restrict Jinv, const int *restrict mat,
                   const double *restrict Btab, const double *restrict chain, const double *restrict taus,
                   long ntimes, long order)
{
    const long steps = order < DEG ? order : DEG;
    for (long c0 = 0; c0 < ncells; c0 += W) {
        const long w = ncells - c0 < W ? ncells - c0 : W;
        double u[NB][5][W], r[NB][5][W], g0[NB][5][W], g1[NB][5][W], q[MAXT][NB][5][W], jac[4][W], Bl[11][W];
        long cl[W];
        for (long l = 0; l < W; l++) {
            const long c = cells[c0 + (l < w ? l : 0)];
            cl[l] = c;
            for (int j = 0; j < NB; j++)
                for (int k = 0; k < 5; k++) r[j][k][l] = X[5 * (NB * c + j) + k];
            for (int t = 0; t < 4; t++) jac[t][l] = Jinv[4 * c + t];
            for (int t = 0; t < 11; t++) Bl[t][l] = Btab[11 * mat[c] + t];
        }
        for (long i = 0; i < ntimes; i++)
            for (int j = 0; j < NB; j++)
                for (int k = 0; k < 5; k++)
                    for (long l = 0; l < W; l++) q[i][j][k][l] = r[j][k][l];
        const double *j00 = jac[0], *j01 = jac[1], *j10 = jac[2], *j11 = jac[3];
        double coef[MAXT];
        for (long i = 0; i < ntimes; i++) coef[i] = 1.0;
        const double *ch = chain;
        for (int m = 1; m <= DEG; m++) {
            if (m > steps) break;
            const int nin = DIM(DEG - m + 1), nout = DIM(DEG - m);
            const double *V = chain_derivative(g0, g1, &ch, r, nin, nout);
            strong_terms(u, g0, g1, nout, 0, j00, j01, j10, j11);
            for (int i = 0; i < nout; i++)
                for (long l = 0; l < W; l++) {
                    BINV(wv, u[i], Bl, l);
                    for (int k = 0; k < 5; k++) r[i][k][l] = wv[k];
                }
            for (long i = 0; i < ntimes; i++) coef[i] *= taus[i] / (double)m;
            for (int a = 0; a < NB; a++) /* the term at the nodes, into every time's sum */
                for (int k = 0; k < 5; k++) {
                    double t[W] = {0};
                    for (int i = 0; i < nout; i++) {
                        const double v = V[a * nout + i];
                        for (int l = 0; l < W; l++) t[l] += v * r[i][k][l];
                    }
                    for (long i = 0; i < ntimes; i++)
                        for (int l = 0; l < W; l++) q[i][a][k][l] += coef[i] * t[l];
                }
        }
        for (long i = 0; i < ntimes; i++)
            for (long l = 0; l < w; l++)
                for (int a = 0; a < NB; a++)
                    for (int k = 0; k < 5; k++) Q[i * stride + 5 * (NB * cl[l] + a) + k] = q[i][a][k][l];
    }
}

/* The kinetic and strain energy of X - X0 on the owned cells (X0: the uniform initial state, 5
 * values), in blocks of W cells: what the numba kernel cell_energies in hydrofrac/matfree.py
 * computes for a cell-contiguous space, 1/2 u^T M_c u with M_c = |det J| Mref kron B (B: rho for
 * v, the compliance for sigma; Ctab[mat[c]] = rho, rho, the 3x3 compliance block).
 * out[0], out[1] = kinetic, strain (lane sums, added at the end). */
void cell_energies(double *restrict out, const double *restrict X, const double *restrict X0, long ncells,
                   const double *restrict Mref, const double *restrict absdet, const int *restrict mat,
                   const double *restrict Ctab)
{
    double kin[W] = {0}, strain[W] = {0};
    for (long c0 = 0; c0 < ncells; c0 += W) {
        const long w = ncells - c0 < W ? ncells - c0 : W;
        double u[NB][5][W], b[NB][5][W], wt[W];
        for (long l = 0; l < W; l++) {
            const long c = c0 + (l < w ? l : 0);
            const double *B = Ctab + 11 * mat[c];
            wt[l] = l < w ? absdet[c] : 0.0;
            for (int j = 0; j < NB; j++) {
                const double *x = X + 5 * (NB * c + j);
                const double u0 = x[0] - X0[0], u1 = x[1] - X0[1], u2 = x[2] - X0[2], u3 = x[3] - X0[3],
                             u4 = x[4] - X0[4];
                u[j][0][l] = u0;
                u[j][1][l] = u1;
                u[j][2][l] = u2;
                u[j][3][l] = u3;
                u[j][4][l] = u4;
                b[j][0][l] = B[0] * u0;
                b[j][1][l] = B[1] * u1;
                b[j][2][l] = B[2] * u2 + B[3] * u3 + B[4] * u4;
                b[j][3][l] = B[5] * u2 + B[6] * u3 + B[7] * u4;
                b[j][4][l] = B[8] * u2 + B[9] * u3 + B[10] * u4;
            }
        }
        double ek[W] = {0}, es[W] = {0};
        for (int a = 0; a < NB; a++)
            for (int j = 0; j < NB; j++) {
                const double m = Mref[a * NB + j];
                for (long l = 0; l < W; l++) {
                    ek[l] += m * (b[a][0][l] * u[j][0][l] + b[a][1][l] * u[j][1][l]);
                    es[l] += m * (b[a][2][l] * u[j][2][l] + b[a][3][l] * u[j][3][l] + b[a][4][l] * u[j][4][l]);
                }
            }
        for (long l = 0; l < W; l++) {
            kin[l] += wt[l] * ek[l];
            strain[l] += wt[l] * es[l];
        }
    }
    double k = 0.0, s = 0.0;
    for (long l = 0; l < W; l++) {
        k += kin[l];
        s += strain[l];
    }
    out[0] = 0.5 * k;
    out[1] = 0.5 * s;
}
