"""Effects: physical or sensor effects a nominal model may lack, declared exactly like third-party ones.

Modules: :mod:`.builtin` (air-drag, wind, extra-damping, grip-compliance; its hook registers every
built-in), :mod:`.physics` (table-slope, sticky-patch, heavy-hem), :mod:`.robot` (duration-scale,
grasp-patch: how the robot executes the scenario; model edits for ``mujoco-flex``), :mod:`.sensor`
(calibration-offset, point-noise, time-offset, table-unseen; ``kind = "sensor"``), :mod:`.material`
(aniso-stretch: the fabric's warp-to-weft stiffness ratio), :mod:`.rig` (arm-mask, camera-offset: the depth rig's
two merged cameras and its masked-out arm; ``kind = "sensor"``) and :mod:`.generic` (generic force terms,
``generic = True``, not ordinary diagnosis candidates).

Writing an effect (the effect door; no backend needs to know its name)::

    import numpy as np
    from softsbi import Effect, Param, ParamSpace, hookimpl

    class HeavyHem(Effect):
        '''Extra weight hem_density * spacing * g on the border vertices. Off at 0 kg/m.'''
        name = "my-hem"
        description = "extra weight along the cloth's edges (kg/m)"

        def param_space(self):
            return ParamSpace([Param("hem_density", 0.0, 0.05, "kg/m")])

        def force(self, x, v, t, theta, ctx):      # x, v (N, 3) m, m/s; t s; theta: own parameters
            w = theta["hem_density"] * ctx.spacing  # ctx: VertexContext (mass, area, x0, table_z, edges...)
            return ctx.edges[:, None] * w * ctx.gravity[None, :]   # (N, 3) newtons

    @hookimpl
    def softsbi_effects():
        return [HeavyHem]

The three doors (:class:`softsbi.core.interfaces.Effect`): override ``force`` (a per-vertex force
field, applied before every physics step by every backend with ``"force"`` in its
``effect_kinds``), or list a backend in ``model_edits`` and override ``edit_model`` (that backend's
model description, edited before it is built; used there in place of the force field), or override
``observe`` (an observation transform of the finished rollout, with a seeded generator: sensor
effects, ``kind = "sensor"``). ``Simulator.supports(effect)`` says whether a backend can apply it
and, if not, which door it lacks; ``softsbi plugins`` lists the effects each backend supports.
Door support today: ``mujoco-flex`` all three (forces through ``xfrc_applied`` of the flex vertex
bodies; model edits on the spec dict, and on the compiled model where MJCF cannot say it: aniso-stretch's
orthotropic membrane); ``pybullet-massspring`` observation transforms only (PyBullet's ``applyExternalForce``
does not act on deformable nodes).

An effect whose parameters the estimator's default summaries cannot see names the estimator options that
make them identifiable in ``estimator_options`` (a class attribute); a fit whose model has the effect passes
them to an estimator that has them, under the user's own (:func:`softsbi.workflows.fit.run.estimator_options`).
Point noise asks for ``{"frame_thickness": True}``.
"""
