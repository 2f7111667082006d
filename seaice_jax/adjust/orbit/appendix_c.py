"""The 1985 orbit-parameter search of source 001, Appendix C (Figure C-1), kept as the baseline.

Faithful to the published procedure, in degrees as the original:

1. Initial spans from the control points (eqs C-1, C-2): orbital span γ = (Lt_max − Lt_min)·N/|s_max − s_min|,
   scanner span β = (Ln_max − Ln_min)·N/|p_max − p_min|; node φ0 = 0; the first orbital angle at the orbit's
   apex (γ_1 = 0, i.e. η_1 = 90°).
2. Edge angles: β_1 = β·(p_s − 1)/(N − 1), β_N = β_1 − β; η_N = η_1 ± γ.
3. Inner loop (step 4): compute DLAT, DLONG at the control points; move the node by the mean longitude error
   (C-15) and the orbital angles by the mean latitude error (C-16, C-17, sign reversed for northbound passes)
   until |mean DLAT| < 0.0001°.
4. Orbital-span loop (steps 5-6): while the figure of merit SD = SL_t² + SL_n² (eqs C-10, C-11: standard
   deviations of DLAT and DLONG) decreases, adjust γ by f_γ = 0.01 times the sum of latitude deviations from their
   mean, signed by the station's scan line relative to the mean scan line (C-20); on an increase, restore the
   last γ.
5. Scanner-span loop (steps 7-8): the same for β with the longitude deviations signed by pixel (C-21,
   f_β = 0.01), back to 2, until SD stops decreasing.
6. Subtrack pixel: binary search (the second part of Appendix C): test p_s = i and i ± n, centre on the best,
   halve n until n = 1; n starts at half the 2048-pixel scanner frame.

Where the printed text is ambiguous or garbled (the signs of C-16/C-17 relative to the printed convention; how
the deviations are summed in steps 6 and 8), the reading that makes the procedure converge under the DESIGN.md
conventions is used; each such choice is marked in the code. Iteration caps replace the operator's patience.
"""

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from seaice_jax.geometry.scan import ScanModel

_MAX_INNER = 200
_MAX_SPAN_STEPS = 5000


def _model(orbit, direction, n_pixels, n_scans, subtrack, beta_span, eta_first, gamma_span, node):
    return ScanModel(jnp.radians(beta_span), subtrack, jnp.radians(eta_first), jnp.radians(gamma_span),
                     jnp.radians(node), orbit, direction, n_pixels, n_scans)


def appendix_c_search(control, orbit, direction, n_pixels, n_scans, start_subtrack=0.0,
                      search_span=2048, f_gamma=0.01, f_beta=0.01, initial_spans="auto"):
    """Run the Appendix C search. Returns ``(model, evaluations)`` (evaluations of the control positions).

    The loops of Figure C-1 run as ``lax.while_loop`` inside one compiled function per subtrack trial; the
    arithmetic and the order of the steps are the 1985 procedure's.

    Args:
        n_pixels, n_scans: the image's size, pixels per scan line and scan lines.
        start_subtrack, search_span: the binary search starts at this pixel with steps of half the span.
        f_gamma, f_beta: the adjustment factors (0.01 by default, as in 1985).
        initial_spans: ``(orbital, scanner)`` starting spans in degrees as an operator would enter them; ``None``
            takes the program's own estimates, eqs C-1 and C-2; ``"auto"`` (default) does what the manual tells
            the operator: try the program's estimates and, since "if the user does not know the approximate
            values of the true angles, the use of 1,1 usually works", also 1,1, keeping the smaller figure of
            merit.
    """
    if isinstance(initial_spans, str):
        if initial_spans != "auto":
            raise ValueError(f"initial_spans must be 'auto', None or (orbital, scanner), got {initial_spans!r}")
        options = dict(start_subtrack=start_subtrack, search_span=search_span, f_gamma=f_gamma, f_beta=f_beta)
        runs = [_search(control, orbit, direction, n_pixels, n_scans, initial_spans=spans, **options)
                for spans in (None, (1.0, 1.0))]
        model = min(runs, key=lambda run: run[2])[0]
        return model, sum(run[1] for run in runs)
    model, evaluations, _ = _search(control, orbit, direction, n_pixels, n_scans, start_subtrack, search_span,
                                    f_gamma, f_beta, initial_spans)
    return model, evaluations


def _search(control, orbit, direction, n_pixels, n_scans, start_subtrack, search_span, f_gamma, f_beta,
            initial_spans):
    """One Appendix C search from given starting spans: ``(model, evaluations, figure of merit)``."""
    pixel, scan = np.asarray(control.pixel), np.asarray(control.scan)
    lat, lon = np.degrees(np.asarray(control.latitude)), np.degrees(np.asarray(control.longitude))
    sign = 1.0 if direction == "south" else -1.0
    if initial_spans is None:
        i_max, i_min = np.argmax(lat), np.argmin(lat)
        gamma0 = abs((lat[i_max] - lat[i_min]) * n_scans / max(abs(scan[i_max] - scan[i_min]), 1.0))  # C-1
        j_max, j_min = np.argmax(lon), np.argmin(lon)
        beta0 = abs((lon[j_max] - lon[j_min]) * n_pixels / max(abs(pixel[j_max] - pixel[j_min]), 1.0))  # C-2
    else:
        gamma0, beta0 = (float(x) for x in initial_spans)
    scan_side = jnp.sign(scan - scan.mean())
    pixel_side = jnp.sign(pixel - pixel.mean())

    def deviations(subtrack, beta, eta_first, gamma, node):
        m = _model(orbit, direction, n_pixels, n_scans, subtrack, beta, eta_first, gamma, node)
        clat, clon = m.forward(control.pixel, control.scan)
        return jnp.degrees(clat) - lat, (jnp.degrees(clon) - lon + 180.0) % 360.0 - 180.0  # C-8, C-9

    def merit(dlat, dlon):  # eqs C-10, C-11; SD as the printout's "sum of the squares"
        return jnp.var(dlat, ddof=1) + jnp.var(dlon, ddof=1)

    def inner(subtrack, eta_first, node, gamma, beta):
        """Step 4: node and orbital angles follow the mean errors until |mean DLAT| < 0.0001°."""
        def body(state):
            eta_first, node, dlat, dlon, count = state
            node = (node - jnp.mean(dlon) + 180.0) % 360.0 - 180.0  # C-15
            # C-16, C-17: with η increasing southward on a southbound pass a too-northern solution needs a
            # larger η (the printed sign refers to the source's γ); reversed for northbound passes.
            eta_first = eta_first + sign * jnp.mean(dlat)
            return (eta_first, node, *deviations(subtrack, beta, eta_first, gamma, node), count + 1)

        state = (eta_first, node, *deviations(subtrack, beta, eta_first, gamma, node), 1)
        eta_first, node, dlat, dlon, count = lax.while_loop(
            lambda s: (jnp.abs(jnp.mean(s[2])) >= 1e-4) & (s[4] < _MAX_INNER), body, state)
        return eta_first, node, merit(dlat, dlon), dlat, dlon, count

    def orbital_span_loop(subtrack, eta_first, node, gamma, beta):
        """Steps 5-6: adjust γ (C-20) while SD decreases; restore the last γ on an increase."""
        eta_first, node, sd, dlat, _, count = inner(subtrack, eta_first, node, gamma, beta)

        def body(state):
            (eta_first, node, gamma, sd, dlat), _, _, count, steps = state
            last = (eta_first, node, gamma, sd)
            gamma_new = gamma + f_gamma * jnp.sum((dlat - jnp.mean(dlat)) * scan_side)
            eta_new, node_new, sd_new, dlat_new, _, n = inner(subtrack, eta_first, node, gamma_new, beta)
            return (eta_new, node_new, gamma_new, sd_new, dlat_new), last, sd, count + n, steps + 1

        state = ((eta_first, node, gamma, sd, dlat), (eta_first, node, gamma, sd), jnp.inf, count, 0)
        _, last, _, count, _ = lax.while_loop(
            lambda s: (s[0][3] < s[2]) & (s[4] < _MAX_SPAN_STEPS), body, state)
        return (*last, count)

    @jax.jit
    def fit_for_subtrack(subtrack):
        """Figure C-1 for one subtrack pixel: steps 2-8, returning the best (SD, η_1, φ0, γ, β, evaluations)."""
        def body(state):
            eta_first, node, gamma, beta, _, sd_before, best, count, steps = state
            eta_first, node, gamma, sd, n = orbital_span_loop(subtrack, eta_first, node, gamma, beta)
            best = lax.cond(sd < best[0], lambda: (sd, eta_first, node, gamma, beta), lambda: best)
            # step 8, C-21: pixels increase to the left of the flight, so a too-small scanner span leaves the
            # high-pixel stations short of their longitude deviation from the mean
            _, dlon = deviations(subtrack, beta, eta_first, gamma, node)
            beta_new = beta - sign * f_beta * jnp.sum((dlon - jnp.mean(dlon)) * pixel_side)
            return eta_first, node, gamma, beta_new, sd_before, sd, best, count + n + 1, steps + 1

        def keep_going(state):  # step 7: stop when the last scanner adjustment brought no improvement
            _, _, _, _, sd_before, sd, _, _, steps = state
            return ((steps == 0) | (sd < sd_before)) & (steps < _MAX_SPAN_STEPS)

        start = (90.0, 0.0, gamma0, beta0, jnp.inf, jnp.inf, (jnp.inf, 90.0, 0.0, gamma0, beta0), 0, 0)
        state = lax.while_loop(keep_going, body, start)
        return state[6], state[7]

    cache = {}

    def score(subtrack):
        if subtrack not in cache:
            best, count = fit_for_subtrack(jnp.asarray(subtrack, float))
            cache[subtrack] = (tuple(float(x) for x in best), int(count))
        return cache[subtrack][0][0]

    centre, step = float(start_subtrack), search_span // 2
    score(centre)
    while step >= 1:  # the binary search on the subtrack pixel
        centre = min((centre - step, centre, centre + step), key=score)
        step //= 2
    merit_value, eta_first, node, gamma, beta = cache[centre][0]
    evaluations = sum(count for _, count in cache.values())
    model = _model(orbit, direction, n_pixels, n_scans, centre, beta, eta_first, gamma, node)
    return model, evaluations, merit_value
