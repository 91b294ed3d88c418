"""Marker scale (an arm's, kinds.arm.model.ArmModel): each sheet of printed markers printed larger than typed.

    p_tool = p0 + t + ((1 + m) Exp(r) - I)(p0 - c)      the points effect's marker (t, r about its centre c), its
                                                         corners (1 + m) times as far from c as dataset.json says

A printer set to "actual size" prints a few tenths of a percent off (its paper feed, its drum or head, the paper's
humidity), and every marker of one sheet shares that scale (dataset.json: a marker corner's `sheet`; a marker that
names none is its own sheet). The markers' printed size is what gives cameras a metric scale: the cameras measure
a sheet's scale against the arm's, not the metre, which only the URDF's link lengths hold (their priors; this
effect's prior is wide against theirs, so the URDF's scale wins; docs/ARM.md "The print's scale"). With the link
lengths free and no priors nothing holds the metre: the identifiability check stops naming this parameter to fix
(at the side measured on the print: --fix marker_scale.<sheet>=measured/typed - 1). Never a silent gauge.

`marker_scale.<sheet>` m (unit 1: relative, 0.001 = 0.1 % larger), prior PRINT_PRIOR.
"""

from naocal.solver.effect import Effect, Parameter

# A sheet's print scale is off by up to about this much (the prior's std, relative): a few tenths of a percent at
# "actual size" (kinds/arm/sim.py's PRINT_SCALE_ERROR draws 0.3 %), 3-6 % when fitted to a page of the other size
# (Letter on A4, A4 on Letter). Wide against what the link lengths' priors know of the arm's scale (2 mm each: 0.24 %
# on the dual arm) so that the URDF holds the metre: at 1 % about 10 % of the sheets' mean error went into the arm
# (seed 6: tracker 1.17 x its noise), at 2 % about 3 % (1.02 x; docs/ARM.md "The print's scale").
PRINT_PRIOR = 2e-2


class MarkerScale(Effect):
    name = "marker_scale"
    order = 84
    summary = "print scale error of each sheet of markers (their corners further from their centres), relative"
    prior_size = {"1": PRINT_PRIOR}
    # Last of the arm's gauges: of the scale the data cannot tell between the arm's lengths and the print, the
    # print's is the one to fix, but never silently (arm_gauge): at 0 it would be the typed size, the error itself.
    gauge_priority = 8
    arm_gauge = False
    undetermined_hint = ("the metric scale: the link lengths are free and the print's scale is unknown, nothing "
                         "else holds it; fix {name} at the side measured on the print (--fix {name}=MEASURED/TYPED-1),"
                         " or fit with the priors on (the URDF's link lengths hold it)")

    def arm_parameters(self, arm):
        return [Parameter(f"marker_scale.{sheet}", self.name, "1", arm.scale, component=sheet, index=k)
                for k, sheet in enumerate(arm.sheet_names)]


EFFECT = MarkerScale()
