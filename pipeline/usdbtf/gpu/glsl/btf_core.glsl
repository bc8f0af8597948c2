// usdbtf BTF evaluation: equation 2 of Koudelka et al. 2003 at arbitrary view and light
// directions, the GPU twin of usdbtf.render (hemisphere.py, shading.py, texture.py).
//
//   I(x, v, l) = f^-1(M * sum_j w_j(v, l) * sum_i U[s_j, i] * c_i(x))
//
// s_j runs over the 3 x 3 samples of the view triangle and the light triangle that
// enclose the local directions (barycentric weights w_j, triangles found on the disc of
// the azimuthal equidistant projection p = theta / 90deg * (cos phi, sin phi)), U is the
// basis, c_i the coefficient textures, M the colour matrix, f the working-domain curve (its
// inverse per channel; a light's intensity and fade multiply after it: btfShadeLight).  Outside the measured region
// a direction takes the nearest boundary point; lights there fade with cos(theta).
//
// Everything but the coefficients lives in one RGBA float texture, "tables", addressed
// as a 1-D array of texels (row-major from the image's top row, width = the texture's
// width).  Layout, written by usdbtf.gpu.tables:
//   texel 0        (width, V, L, G)          G = stored basis groups (4 vectors per texel)
//   texel 1        (K, basisOffset, viewHemisphere, lightHemisphere)
//   texel 2        (dequantOffset, matrixOffset, curve, gamma)   working-domain curve:
//                  0 linear, 1 power (inverse d^gamma), 2 sRGB (usdbtf.compress.domain)
//   texel 3        (directoryOffset, tileWidth, tileHeight, repeat)   1 = wrap, 0 = clamp
//   basis          basisOffset (maxCode, S, G, codeOffset)   S = V * L samples; maxCode: the codes'
//                  storage (255 uint8, 65535 uint16, 1 half; for readers of the one copy,
//                  usdbtf.gpu.tables.unpack); codeOffset: added to every code (2^23 for integer
//                  codes: one float exponent, smaller files; 0 for halves and in older tables),
//                  or -1: the codes are in the basis page (schema 4, below), not here
//                  basisOffset + 1 + 2g = scale, + 2 + 2g = bias of vectors 4g..4g+3
//                  basisOffset + 1 + 2G + g * S + view * L + light: the stored codes of vectors
//                  4g..4g+3 at that sample plus codeOffset (value = code * scale + bias, the
//                  offset subtracted per texel, exactly, and de-quantised here)
//   hemisphere h   h+0 (origin.x, origin.y, cell, grid)   h+1 (candidateTexels, triangles,
//                  boundaryEdges, 0)   h+2 (gridOffset, triangleOffset, boundaryOffset, 0)
//                  grid cell (x, y): candidateTexels texels of 4 triangle ids (-1 = none)
//                  triangle t: (a.x, a.y, i0, i1) (inv00, inv01, inv10, inv11) (i2, 0, 0, 0)
//                  boundary e: (a.x, a.y, b.x, b.y) (i0, i1, 0, 0)
//   dequant        pack p: dequantOffset + 2p = scale, + 2p + 1 = bias (stored = t * scale + bias)
//   matrix         matrixOffset + r: row r of M
//   directory      directoryOffset + p: (page, x0, y0, maxCode): pack p is the tile whose top-left
//                  texel is column x0, image row y0 (from the top) of page `page`; maxCode: its
//                  codes' storage (as the basis's; the shader reads normalised values)
// Coefficient pack p = 3 g + c holds colour channel c of vectors 4g..4g+3; the packs are
// tiles of at most BTF_MAX_PAGES - 1 RGBA textures ("pages"), filtered here (btfPack).
// Basis page (schema 4, integer codes; page slot BTF_MAX_PAGES - 1, 8-bit RGBA): group g of
// vectors 4g..4g+3 is a V x L image of the codes' high bytes (image rows = views, from the
// top; columns = lights) above a V x L image of their low bytes; groups fill a column, then
// the next, L texels to the right: as few columns as 16384 rows allow (16384 / (2 V) groups
// each), evenly filled (usdbtf.compress.packs.basis_page, basis_page_column).
//
// Environments (Storm glslfx, MaterialX genglsl, the headless harness) include this text
// unchanged after the definitions usdbtf.gpu.shaders.core_source() puts in front of it
// (BTF_PAGE_PARAMS / BTF_PAGE_ARGS: the page samplers btfPage00.. as function parameters and
// arguments, BTF_PAGE_FETCH: a texelFetch on page `page`), and supply: the tables sampler, the
// pages, the texture coordinate, the frame, the lights.  Parameter names carry a btf prefix:
// Storm's MaterialX code defines a macro named after every texture input ("tables",
// "page00"), which would rewrite a parameter of that name.
//
// OSL (Cycles, MaterialX genosl) gets these functions translated mechanically from this text
// (usdbtf.gpu.glsl_to_osl, the types in osl_glsl_types.h), so the code keeps to the subset that
// translation takes: no ?: choosing between vectors, no writes to in-parameters (OSL passes
// arguments by reference), no arrays, no block comments, no write to a swizzle.

#define BTF_HALF_PI 1.5707963267948966
#define BTF_PI 3.141592653589793
// Query points this close outside a triangle (disc units) still count as inside:
// float32 rounding on shared edges and on the outermost ring.
#define BTF_INSIDE_EPS 1e-5

// Texel ``address`` of the tables, counted along the image's rows from its top row (the
// file's first row).  Renderers upload an image bottom row first (Storm's Hio, MaterialX's
// loaders: texture coordinate t = 0 at the bottom), so image row r is texture row h - 1 - r.
vec4 btfFetch(sampler2D btfTables, int address)
{
    ivec2 size = textureSize(btfTables, 0);
    return texelFetch(btfTables, ivec2(address % size.x, size.y - 1 - address / size.x), 0);
}

// Azimuthal equidistant projection of a tangent-frame direction (z = normal).
vec2 btfProject(vec3 d)
{
    float rho = length(d.xy);
    float theta = atan(rho, d.z);
    if (rho > 0.0) {
        return d.xy * (theta / BTF_HALF_PI / rho);
    }
    return vec2(0.0);
}

// Orthonormal frame as the CPU renderer builds it: the normal, the tangent made
// perpendicular to it, bitangent = N x T flipped to agree with the given bitangent.
mat3 btfFrame(vec3 normal, vec3 tangent, vec3 bitangent)
{
    vec3 n = normalize(normal);
    vec3 t = normalize(tangent - n * dot(tangent, n));
    vec3 b = cross(n, t);
    if (dot(b, bitangent) < 0.0) {
        b = -b;
    }
    return mat3(t, b, n);
}

// A direction in the frame's coordinates (x = tangent, y = bitangent, z = normal).
vec3 btfLocal(mat3 frame, vec3 d)
{
    return vec3(dot(d, frame[0]), dot(d, frame[1]), dot(d, frame[2]));
}

// The measured samples enclosing local direction d on hemisphere table h: indices,
// weights (summing to 1) and the polar angle (degrees) of the point interpolated.
void btfLookup(sampler2D btfTables, int h, vec3 d, out ivec3 index, out vec3 weight, out float thetaUsed)
{
    vec4 h0 = btfFetch(btfTables, h);
    vec4 h1 = btfFetch(btfTables, h + 1);
    vec4 h2 = btfFetch(btfTables, h + 2);
    vec2 q = btfProject(d);
    int grid = int(h0.w);
    int candidateTexels = int(h1.x);
    index = ivec3(0);
    weight = vec3(1.0, 0.0, 0.0);
    thetaUsed = length(q) * 90.0;
    float best = -1e30;
    if (int(h1.y) > 0) {
        ivec2 cell = ivec2(floor((q - h0.xy) / h0.z));
        if (all(greaterThanEqual(cell, ivec2(0))) && all(lessThan(cell, ivec2(grid)))) {
            int base = int(h2.x) + (cell.y * grid + cell.x) * candidateTexels;
            for (int c = 0; c < candidateTexels; ++c) {
                vec4 ids = btfFetch(btfTables, base + c);
                for (int j = 0; j < 4; ++j) {
                    int t = int(ids[j]);
                    if (t < 0) {
                        continue;
                    }
                    int at = int(h2.y) + 3 * t;
                    vec4 a = btfFetch(btfTables, at);
                    vec4 inv = btfFetch(btfTables, at + 1);
                    vec2 rel = q - a.xy;
                    vec2 uv = vec2(inv.x * rel.x + inv.y * rel.y, inv.z * rel.x + inv.w * rel.y);
                    vec3 bary = vec3(1.0 - uv.x - uv.y, uv.x, uv.y);
                    float score = min(bary.x, min(bary.y, bary.z));
                    if (score > best) {
                        best = score;
                        index = ivec3(int(a.z), int(a.w), int(btfFetch(btfTables, at + 2).x));
                        weight = bary;
                    }
                }
            }
        }
    }
    if (best >= -BTF_INSIDE_EPS) {
        weight = max(weight, vec3(0.0));
        weight /= weight.x + weight.y + weight.z;
        return;
    }
    // Outside the triangulated region: the nearest point of its boundary.
    float nearest = 1e30;
    int edges = int(h1.z);
    for (int e = 0; e < edges; ++e) {
        vec4 ab = btfFetch(btfTables, int(h2.z) + 2 * e);
        vec4 ids = btfFetch(btfTables, int(h2.z) + 2 * e + 1);
        vec2 along = ab.zw - ab.xy;
        float len2 = dot(along, along);
        float t = len2 > 0.0 ? clamp(dot(q - ab.xy, along) / len2, 0.0, 1.0) : 0.0;
        vec2 p = ab.xy + t * along;
        float d2 = dot(q - p, q - p);
        if (d2 < nearest) {
            nearest = d2;
            index = ivec3(int(ids.x), int(ids.y), 0);
            weight = vec3(1.0 - t, t, 0.0);
            thetaUsed = length(p) * 90.0;
        }
    }
}

// Measured images include the light's foreshortening; beyond the outermost measured
// ring the boundary value is scaled by cos(theta_l) / cos(theta_boundary).
float btfLightFade(vec3 l, float thetaUsed)
{
    float cosQ = l.z / max(length(l), 1e-30);
    float cosB = cos(radians(thetaUsed));
    return cosQ < cosB ? max(cosQ, 0.0) / max(cosB, 1e-12) : 1.0;
}

// The view triangle of local view direction v.
void btfViewLookup(sampler2D btfTables, vec3 v, out ivec3 viewIndex, out vec3 viewWeight)
{
    float unused;
    btfLookup(btfTables, int(btfFetch(btfTables, 1).z), v, viewIndex, viewWeight, unused);
}

// The working domain's inverse curve, per channel (texel 2: z = curve, w = gamma);
// negative values clamp to 0 first, as usdbtf.compress.domain.Domain.inverse does.
vec3 btfInverseCurve(sampler2D btfTables, vec3 d)
{
    vec4 h2 = btfFetch(btfTables, 2);
    int curve = int(h2.z);
    if (curve == 0) {
        return d;
    }
    vec3 c = max(d, vec3(0.0));
    if (curve == 1) {
        return pow(c, vec3(h2.w));
    }
    return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), vec3(greaterThan(c, vec3(0.04045))));
}

// Texel (x, y) of page `page`, x from the left, y an image row from the top: renderers
// upload an image bottom row first, so image row y is texture row height - 1 - y.
vec4 btfPageTexel(BTF_PAGE_PARAMS, int page, int x, int y)
{
    BTF_PAGE_FETCH
    return vec4(0.0);
}

// Coefficient pack p at texture coordinate st (t up, as the CPU renderer: texel centres at
// (i + 0.5) / size), bilinear from the four nearest texels of its own tile, wrapped or
// clamped inside the tile (texel 3.w), the CPU renderer's filter="bilinear".
vec4 btfPack(sampler2D btfTables, BTF_PAGE_PARAMS, int p, vec2 st)
{
    vec4 h3 = btfFetch(btfTables, 3);
    vec4 at = btfFetch(btfTables, int(h3.x) + p);
    ivec2 size = ivec2(h3.yz);
    vec2 f = vec2(st.x, 1.0 - st.y) * vec2(size) - 0.5;
    vec2 base = floor(f);
    vec2 w = f - base;
    ivec2 i0 = ivec2(base);
    ivec2 i1 = i0 + ivec2(1);
    if (h3.w > 0.5) {
        i0 = ((i0 % size) + size) % size;
        i1 = ((i1 % size) + size) % size;
    } else {
        i0 = clamp(i0, ivec2(0), size - 1);
        i1 = clamp(i1, ivec2(0), size - 1);
    }
    int page = int(at.x);
    int x0 = int(at.y);
    int y0 = int(at.z);
    vec4 a = btfPageTexel(BTF_PAGE_ARGS, page, x0 + i0.x, y0 + i0.y);
    vec4 b = btfPageTexel(BTF_PAGE_ARGS, page, x0 + i1.x, y0 + i0.y);
    vec4 c = btfPageTexel(BTF_PAGE_ARGS, page, x0 + i0.x, y0 + i1.y);
    vec4 d = btfPageTexel(BTF_PAGE_ARGS, page, x0 + i1.x, y0 + i1.y);
    return mix(mix(a, b, w.x), mix(c, d, w.x), w.y);
}

// The photometric convention (usdbtf.photometry): a BTF value is the radiance under a light of
// irradiance pi * W (W: the white level, what a white Lambertian lit head-on reads), so under
// irradiance E the radiance is value * E / (pi * W).  Every environment multiplies a light's
// irradiance by this before btfShadeLight.
float btfRadiancePerIrradiance(float whiteLevel)
{
    return 1.0 / (BTF_PI * max(whiteLevel, 1e-30));
}

// Working space -> the renderer's rendering space (btf:renderingColorSpace, issue 40): the rows of
// the matrix usdbtf package computed with OCIO (linear Rec.709 by default, what UsdPreviewSurface
// colours and Storm's, Blender's and MaterialX's frames mean).  Applied after the inverse curve,
// per light (a light's colour is in the rendering space); the identity rows (an asset packaged
// before it) return working-space values, as such an asset always rendered.
vec3 btfToRendering(vec3 working, vec3 rowR, vec3 rowG, vec3 rowB)
{
    return vec3(dot(rowR, working), dot(rowG, working), dot(rowB, working));
}

// One light's working-space radiance at texture coordinate st from the first k basis
// vectors: per group of 4 vectors, the 3 x 3 basis rows blended with weights summing to 1
// (in the working domain) dotted with the group's 3 packs, then the colour matrix and the
// inverse curve, then times the light's scale and its fade beyond the measured region --
// radiance factors, so after the curve.  No arrays: any k.
vec3 btfShadeLight(sampler2D btfTables, BTF_PAGE_PARAMS, ivec3 viewIndex, vec3 viewWeight, vec3 l, float scale,
                   vec2 st, int basisCount)
{
    if (scale <= 0.0) {
        return vec3(0.0);
    }
    ivec3 lightIndex;
    vec3 lightWeight;
    float thetaUsed;
    btfLookup(btfTables, int(btfFetch(btfTables, 1).w), l, lightIndex, lightWeight, thetaUsed);
    vec4 h0 = btfFetch(btfTables, 0);
    vec4 h1 = btfFetch(btfTables, 1);
    vec4 h2 = btfFetch(btfTables, 2);
    int lights = int(h0.z);
    int groups = int(h0.w);
    int basis = int(h1.y);
    int samples = int(h0.y) * lights;
    int codes = basis + 1 + 2 * groups;
    int dequant = int(h2.x);
    int matrix = int(h2.y);
    int k = min(basisCount, int(h1.x));
    // Subtracted from each fetched texel before blending: exact (both below 2^24), where
    // subtracting the blended offset would cancel 2^23 against the code's fraction.
    vec4 codeOffset = vec4(btfFetch(btfTables, basis).w);
    int inPage = 0;
    if (codeOffset.x < -0.5) {
        inPage = 1;
    }
    int views = int(h0.y);
    int mostPerColumn = max(1, 16384 / (2 * views));
    int columns = max(1, (groups + mostPerColumn - 1) / mostPerColumn);
    int perColumn = max(1, (groups + columns - 1) / columns);
    vec3 stored = vec3(0.0);
    for (int g = 0; 4 * g < k && g < groups; ++g) {
        // The blended codes, then de-quantised: the bias enters with the weights' sum.
        vec4 row = vec4(0.0);
        float weights = 0.0;
        for (int a = 0; a < 3; ++a) {
            for (int b = 0; b < 3; ++b) {
                float w = viewWeight[a] * lightWeight[b];
                if (w != 0.0) {
                    if (inPage == 1) {
                        // Both bytes read normalised (byte / 255): rounded back to integers.
                        int x = (g / perColumn) * lights + lightIndex[b];
                        int y = (g % perColumn) * 2 * views + viewIndex[a];
                        vec4 high = btfPageTexel(BTF_PAGE_ARGS, BTF_MAX_PAGES - 1, x, y);
                        vec4 low = btfPageTexel(BTF_PAGE_ARGS, BTF_MAX_PAGES - 1, x, y + views);
                        row += w * (floor(high * 255.0 + vec4(0.5)) * 256.0 + floor(low * 255.0 + vec4(0.5)));
                    } else {
                        row += w * (btfFetch(btfTables, codes + g * samples + viewIndex[a] * lights + lightIndex[b]) - codeOffset);
                    }
                    weights += w;
                }
            }
        }
        row = row * btfFetch(btfTables, basis + 1 + 2 * g) + weights * btfFetch(btfTables, basis + 2 + 2 * g);
        row *= vec4(greaterThan(ivec4(k), ivec4(4 * g) + ivec4(0, 1, 2, 3)));
        for (int c = 0; c < 3; ++c) {
            int p = 3 * g + c;
            vec4 value = btfPack(btfTables, BTF_PAGE_ARGS, p, st) * btfFetch(btfTables, dequant + 2 * p)
                       + btfFetch(btfTables, dequant + 2 * p + 1);
            stored[c] += dot(row, value);
        }
    }
    vec3 working = btfInverseCurve(btfTables, vec3(dot(btfFetch(btfTables, matrix).xyz, stored),
                                                dot(btfFetch(btfTables, matrix + 1).xyz, stored),
                                                dot(btfFetch(btfTables, matrix + 2).xyz, stored)));
    return (scale * btfLightFade(l, thetaUsed)) * working;
}
