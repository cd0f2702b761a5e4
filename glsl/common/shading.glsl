// Shading as pure functions of (colour, gradient, light, view): no bindings, no shader inputs.
#ifndef VELLUM_SHADING_GLSL
#define VELLUM_SHADING_GLSL

// Phong (with specular) and diffuse-only colours of a sample of straight colour `rgb`.
// `gradient` is xyz in world units (w, its length where it was stored, is not read); it points
// into denser material, and shading is two-sided. The normal is the gradient made unit length
// where the sample is: a stored gradient interpolated between voxels is shorter than the
// lengths interpolated wherever its direction turns, and dividing by those darkened curved
// surfaces (by 1-3/255 on average on the CT head), and made the gradient a ray caster makes at the
// sample (`shade.glsl`'s `sobel_at`, the same interpolated vector) shade differently from it.
// Below a length of 1e-4 (flat) the sample is unlit. `to_light` and `to_eye` are unit vectors;
// `material` is (ambient, diffuse, specular, _) and `shininess` the specular exponent.
void shade_phong(vec3 rgb, vec4 gradient, vec3 to_light, vec3 to_eye, vec4 material, float shininess,
                 out vec3 phong, out vec3 diffuse) {
    float ka = material.x, kd = material.y, ks = material.z;
    float len = length(gradient.xyz);
    if (len > 1e-4) {
        vec3 n = -gradient.xyz / len;
        diffuse = rgb * (ka + kd * abs(dot(n, to_light)));
        phong = diffuse + vec3(ks * pow(abs(dot(n, normalize(to_light + to_eye))), shininess));
    } else {
        diffuse = rgb * (ka + kd);
        phong = diffuse;
    }
}

#endif
