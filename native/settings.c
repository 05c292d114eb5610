/* settings.c - the defaults of every settings struct in one place (Box2D's types.c is the model),
 * and the checks that reject absurd values with a message naming the field, its unit and the
 * value.
 *
 * The defaults are the Python presets': tc_material_default() is addon/materials.py's "cotton",
 * tc_solver_default() and tc_tear_default() are what tearcloth.Cloth uses when not told otherwise.
 * tests/test_native_defaults.py reads them back through tearcloth._native.defaults() and compares.
 */
#include "core.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

tc_material tc_material_default(void)
{
    /* addon/materials.py MATERIALS["cotton"], field by field (sources of the values are there) */
    tc_material m = {
        .young = 5.0e7, .poisson = 0.3, .thickness = 4.0e-4, .density = 375.0,
        .bending = 5.0e-6, .damping_mass = 3.0, .damping_stiffness = 2.0e-5,
        .tear_stress = 8.0e6, .snap_tolerance = 0.3, .tear_radius = 0.01, .crack_speed_ratio = 0.2,
        .orthotropic = 0, .young_weft = 4.0e7, .shear_modulus = 5.0e5, .grain_angle = 0.0, .tear_stress_weft = 6.5e6,
        .plastic = 0, .yield_stress = 4.0e6, .yield_stress_weft = 3.25e6, .hardening = 2.0,
    };
    return m;
}

tc_solver_settings tc_solver_default(void)
{
    tc_solver_settings s = {.gravity = {0.0, 0.0, -9.81}, .cg_tolerance = 1e-4, .cg_max_iterations = 1000,
                            .max_stretch = 20.0, .contact_max_push = 0.1,
                            .contact_correction = 0.2, .preconditioner = TC_PRECOND_AUTO};
    return s;
}

tc_tear_settings tc_tear_default(void)
{
    /* min_fragment_area 0: a scripted cloth keeps every piece (the add-on's 1 cm^2: settings.py) */
    tc_tear_settings s = {.enabled = 0, .scan_period = 16, .min_angle_deg = 10.0, .min_fragment_area = 0.0};
    return s;
}

#define BAD(...) do { snprintf(msg, msz, __VA_ARGS__); return TC_ERR_INPUT; } while (0)

int tc_material_check(const tc_material *m, char *msg, size_t msz)
{
    if (!(isfinite(m->young) && m->young > 0)) BAD("young (Young's modulus) must be > 0 Pa and finite (got %g)", m->young);
    if (!(m->poisson > -1.0 && m->poisson < 0.5)) BAD("poisson (Poisson ratio) must lie in (-1, 0.5) (got %g)", m->poisson);
    if (!(isfinite(m->thickness) && m->thickness > 0)) BAD("thickness must be > 0 m and finite (got %g)", m->thickness);
    if (!(isfinite(m->density) && m->density > 0)) BAD("density must be > 0 kg/m^3 and finite (got %g)", m->density);
    if (!(isfinite(m->bending) && m->bending >= 0)) BAD("bending (stiffness) must be >= 0 N m and finite (got %g)", m->bending);
    if (!(isfinite(m->damping_mass) && m->damping_mass >= 0)) BAD("damping_mass must be >= 0 1/s (got %g)", m->damping_mass);
    if (!(isfinite(m->damping_stiffness) && m->damping_stiffness >= 0)) BAD("damping_stiffness must be >= 0 s (got %g)", m->damping_stiffness);
    if (!(m->tear_stress > 0)) BAD("tear_stress must be > 0 Pa (got %g)", m->tear_stress);
    if (!(m->snap_tolerance >= 0 && m->snap_tolerance < 0.5)) BAD("snap_tolerance must lie in [0, 0.5) (got %g)", m->snap_tolerance);
    if (!(m->tear_radius >= 0 && m->tear_radius <= 1.0)) BAD("tear_radius must lie in [0, 1] m (got %g)", m->tear_radius);
    if (!(m->crack_speed_ratio > 0 && m->crack_speed_ratio <= 1.0))
        BAD("crack_speed_ratio (fastest tear / Rayleigh wave speed) must lie in (0, 1] (got %g)", m->crack_speed_ratio);
    if (!(isfinite(m->young_weft) && m->young_weft > 0 && m->young_weft <= 1e13))
        BAD("young_weft (Young's modulus along the weft) must lie in (0, 1e13] Pa (got %g)", m->young_weft);
    if (!(isfinite(m->shear_modulus) && m->shear_modulus > 0 && m->shear_modulus <= 1e13))
        BAD("shear_modulus (warp-weft shear modulus G) must lie in (0, 1e13] Pa (got %g)", m->shear_modulus);
    if (m->orthotropic) {
        /* positive definite plane-stress compliance: nu12^2 < E1 / E2 */
        double r = m->young / m->young_weft;
        if (!(m->poisson * m->poisson < r))
            BAD("poisson = %g with young / young_weft = %g: an orthotropic sheet needs poisson^2 < young / young_weft "
                "(else a stretch could release energy)", m->poisson, r);
    }
    if (!(isfinite(m->grain_angle) && fabs(m->grain_angle) <= 100.0)) BAD("grain_angle must be finite radians within +-100 (got %g)", m->grain_angle);
    if (!(m->tear_stress_weft > 0 && isfinite(m->tear_stress_weft))) BAD("tear_stress_weft must be > 0 Pa (got %g)", m->tear_stress_weft);
    if (!(m->yield_stress > 0 && isfinite(m->yield_stress))) BAD("yield_stress must be > 0 Pa (got %g)", m->yield_stress);
    if (!(m->yield_stress_weft > 0 && isfinite(m->yield_stress_weft))) BAD("yield_stress_weft must be > 0 Pa (got %g)", m->yield_stress_weft);
    if (!(m->hardening >= 0 && m->hardening <= 100.0)) BAD("hardening (H / young) must lie in [0, 100] (got %g)", m->hardening);
    if (m->orthotropic != 0 && m->orthotropic != 1) BAD("orthotropic must be 0 or 1 (got %d)", m->orthotropic);
    if (m->plastic != 0 && m->plastic != 1) BAD("plastic must be 0 or 1 (got %d)", m->plastic);
    if (m->young > 1e13) BAD("young = %g Pa is beyond any sheet material (diamond is ~1e12)", m->young);
    if (m->density > 1e5) BAD("density = %g kg/m^3 is beyond any material", m->density);
    if (m->thickness > 1.0) BAD("thickness = %g m is not a thin sheet", m->thickness);
    return TC_OK;
}

int tc_solver_check(const tc_solver_settings *s, char *msg, size_t msz)
{
    for (int k = 0; k < 3; k++)
        if (!isfinite(s->gravity[k]) || fabs(s->gravity[k]) > 1e4)
            BAD("gravity component %d is not a plausible acceleration (%g m/s^2)", k, s->gravity[k]);
    if (!(s->cg_tolerance > 0 && s->cg_tolerance < 1)) BAD("cg_tolerance must lie in (0, 1) (got %g)", s->cg_tolerance);
    if (s->cg_max_iterations < 1 || s->cg_max_iterations > 100000) BAD("cg_max_iterations must lie in [1, 100000] (got %d)", s->cg_max_iterations);
    if (!(s->max_stretch > 1.0)) BAD("max_stretch must be > 1 (got %g)", s->max_stretch);
    if (!(s->contact_max_push > 0 && isfinite(s->contact_max_push))) BAD("contact_max_push must be > 0 m/s (got %g)", s->contact_max_push);
    if (!(s->contact_correction >= 0 && s->contact_correction <= 1)) BAD("contact_correction must lie in [0, 1] (got %g)", s->contact_correction);
    if (!tc_precond_name(s->preconditioner)) BAD("preconditioner must be auto, jacobi, amg or sgs (got %d)", s->preconditioner);
    return TC_OK;
}

static const char *const PRECOND_NAMES[] = {"auto", "jacobi", "amg", "sgs"};

int tc_precond_from_name(const char *name)
{
    for (int k = 0; k < 4; k++)
        if (name && strcmp(name, PRECOND_NAMES[k]) == 0) return k;
    return -1;
}

const char *tc_precond_name(int p) { return p >= 0 && p < 4 ? PRECOND_NAMES[p] : NULL; }

int tc_tear_check(const tc_tear_settings *s, char *msg, size_t msz)
{
    if (s->scan_period < 1 || s->scan_period > 100000) BAD("scan_period must lie in [1, 100000] (got %d)", s->scan_period);
    if (!(s->min_angle_deg >= 0 && s->min_angle_deg < 30)) BAD("min_angle_deg must lie in [0, 30) (got %g)", s->min_angle_deg);
    if (!(s->min_fragment_area >= 0 && s->min_fragment_area <= 1.0))
        BAD("min_fragment_area must lie in [0, 1] m^2 (got %g)", s->min_fragment_area);
    return TC_OK;
}

#undef BAD
