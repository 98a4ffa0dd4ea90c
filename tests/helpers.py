"""Test helpers: small Mitsuba scenes with closed-form answers."""

#: A Lambertian plane facing a coaxial point light and camera (closed-form radiometry).
PLANE_XML = """\
<scene version="3.0.0">
    <default name="lamp" value="1"/>
    <default name="rho" value="0.5"/>
    <integrator type="path"><integer name="max_depth" value="2"/></integrator>
    <sensor type="perspective" id="camera">
        <float name="fov" value="{fov}"/>
        <transform name="to_world"><lookat origin="0, 0, 0" target="0, 0, 1" up="0, 1, 0"/></transform>
    </sensor>
    <emitter type="point" id="lamp">
        <point name="position" x="0" y="0" z="0"/>
        <spectrum name="intensity" value="$lamp"/>
    </emitter>
    <shape type="rectangle" id="plane">
        <transform name="to_world"><scale x="20" y="20" z="1"/><rotate y="1" angle="180"/><translate z="{d}"/></transform>
        <bsdf type="diffuse"><spectrum name="reflectance" value="$rho"/></bsdf>
    </shape>
</scene>
"""
