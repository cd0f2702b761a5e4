// Shading as pure functions of (colour, gradient, light, view): no bindings, no shader inputs.
#ifndef VELLUM_SHADING_GLSL
#define VELLUM_SHADING_GLSL

// Phong (with specular) and diffuse-only colours of a sample of straight colour `rgb`.
// `gradient` is xyz in world units and w its length; it points into denser material, and shading
// is two-sided. `to_light` and `to_eye` are unit vectors; `material` is (ambient, diffuse,
// specular, _) and `shininess` the specular exponent.
void shade_phong(vec3 rgb, vec4 gradient, vec3 to_light, vec3 to_eye, vec4 material, float shininess,
                 out vec3 phong, out vec3 diffuse) {
    float ka = material.x, kd = material.y, ks = material.z;
    if (gradient.w > 1e-4) {
        vec3 n = -gradient.xyz / gradient.w;
        diffuse = rgb * (ka + kd * abs(dot(n, to_light)));
        phong = diffuse + vec3(ks * pow(abs(dot(n, normalize(to_light + to_eye))), shininess));
    } else {
        diffuse = rgb * (ka + kd);
        phong = diffuse;
    }
}

#endif
