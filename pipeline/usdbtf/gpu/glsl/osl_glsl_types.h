// The GLSL vocabulary btf_core.glsl uses, in OSL: usdbtf.gpu.osl translates the core into OSL
// against these definitions (it renames vec2 -> btfVec2, vec4 -> btfVec4, ivecN -> btfIVecN,
// mat3 -> btfMat3, vec3 -> vector, sampler2D -> string; a constructor T(...) -> btfMakeT(...),
// a swizzle e.g. v.xy -> btf_xy(v), an index v[i] read -> btfAt(v, i)).  Types and
// operators only: no shading in here.  Textures are files read texel by texel, with the
// closest filter at the finest level (btfTexelFetch), the way GLSL's texelFetch reads them.

struct btfVec2 { float x; float y; };
struct btfVec4 { float x; float y; float z; float w; };
struct btfIVec2 { int x; int y; };
struct btfIVec3 { int x; int y; int z; };
struct btfIVec4 { int x; int y; int z; int w; };
struct btfMat3 { vector c0; vector c1; vector c2; };     // columns, as GLSL's mat3

// Constructors (GLSL: T(scalar), T(components), T(other vector type)).
btfVec2 btfMakeVec2(float s) { return btfVec2(s, s); }
btfVec2 btfMakeVec2(float x, float y) { return btfVec2(x, y); }
btfVec2 btfMakeVec2(btfIVec2 v) { return btfVec2(float(v.x), float(v.y)); }
vector btfMakeVec3(float s) { return vector(s, s, s); }
vector btfMakeVec3(float x, float y, float z) { return vector(x, y, z); }
vector btfMakeVec3(vector v) { return v; }
btfVec4 btfMakeVec4(float s) { return btfVec4(s, s, s, s); }
btfVec4 btfMakeVec4(float x, float y, float z, float w) { return btfVec4(x, y, z, w); }
btfVec4 btfMakeVec4(btfIVec4 v) { return btfVec4(float(v.x), float(v.y), float(v.z), float(v.w)); }
btfIVec2 btfMakeIVec2(int s) { return btfIVec2(s, s); }
btfIVec2 btfMakeIVec2(int x, int y) { return btfIVec2(x, y); }
btfIVec2 btfMakeIVec2(btfVec2 v) { return btfIVec2(int(v.x), int(v.y)); }
btfIVec3 btfMakeIVec3(int s) { return btfIVec3(s, s, s); }
btfIVec3 btfMakeIVec3(int x, int y, int z) { return btfIVec3(x, y, z); }
btfIVec4 btfMakeIVec4(int s) { return btfIVec4(s, s, s, s); }
btfIVec4 btfMakeIVec4(int x, int y, int z, int w) { return btfIVec4(x, y, z, w); }
btfMat3 btfMakeMat3(vector a, vector b, vector c) { return btfMat3(a, b, c); }

// Swizzles.
btfVec2 btf_xy(vector v) { return btfVec2(v[0], v[1]); }
btfVec2 btf_xy(btfVec4 v) { return btfVec2(v.x, v.y); }
btfVec2 btf_yz(btfVec4 v) { return btfVec2(v.y, v.z); }
btfVec2 btf_zw(btfVec4 v) { return btfVec2(v.z, v.w); }
vector btf_xyz(btfVec4 v) { return vector(v.x, v.y, v.z); }

// Component reads v[i].
float btfAt(vector v, int i) { return v[i]; }
float btfAt(btfVec4 v, int i) { return i == 0 ? v.x : i == 1 ? v.y : i == 2 ? v.z : v.w; }
float btfAt(btfVec2 v, int i) { return i == 0 ? v.x : v.y; }
int btfAt(btfIVec2 v, int i) { return i == 0 ? v.x : v.y; }
int btfAt(btfIVec4 v, int i) { return i == 0 ? v.x : i == 1 ? v.y : i == 2 ? v.z : v.w; }
int btfAt(btfIVec3 v, int i) { return i == 0 ? v.x : i == 1 ? v.y : v.z; }
vector btfAt(btfMat3 m, int i) { return i == 0 ? m.c0 : i == 1 ? m.c1 : m.c2; }

// Arithmetic, component-wise as in GLSL.
btfVec2 __operator__add__(btfVec2 a, btfVec2 b) { return btfVec2(a.x + b.x, a.y + b.y); }
btfVec2 __operator__sub__(btfVec2 a, btfVec2 b) { return btfVec2(a.x - b.x, a.y - b.y); }
btfVec2 __operator__sub__(btfVec2 a, float b) { return btfVec2(a.x - b, a.y - b); }
btfVec2 __operator__mul__(btfVec2 a, btfVec2 b) { return btfVec2(a.x * b.x, a.y * b.y); }
btfVec2 __operator__mul__(btfVec2 a, float b) { return btfVec2(a.x * b, a.y * b); }
btfVec2 __operator__mul__(float a, btfVec2 b) { return btfVec2(a * b.x, a * b.y); }
btfVec2 __operator__div__(btfVec2 a, float b) { return btfVec2(a.x / b, a.y / b); }
btfVec4 __operator__add__(btfVec4 a, btfVec4 b) { return btfVec4(a.x + b.x, a.y + b.y, a.z + b.z, a.w + b.w); }
btfVec4 __operator__sub__(btfVec4 a, btfVec4 b) { return btfVec4(a.x - b.x, a.y - b.y, a.z - b.z, a.w - b.w); }
btfVec4 __operator__mul__(btfVec4 a, btfVec4 b) { return btfVec4(a.x * b.x, a.y * b.y, a.z * b.z, a.w * b.w); }
btfVec4 __operator__mul__(btfVec4 a, float b) { return btfVec4(a.x * b, a.y * b, a.z * b, a.w * b); }
btfVec4 __operator__mul__(float a, btfVec4 b) { return btfVec4(a * b.x, a * b.y, a * b.z, a * b.w); }
btfIVec2 __operator__add__(btfIVec2 a, btfIVec2 b) { return btfIVec2(a.x + b.x, a.y + b.y); }
btfIVec2 __operator__sub__(btfIVec2 a, int b) { return btfIVec2(a.x - b, a.y - b); }
btfIVec2 __operator__mod__(btfIVec2 a, btfIVec2 b) { return btfIVec2(a.x % b.x, a.y % b.y); }
btfIVec4 __operator__add__(btfIVec4 a, btfIVec4 b) { return btfIVec4(a.x + b.x, a.y + b.y, a.z + b.z, a.w + b.w); }

// Built-in functions on these types.
float dot(btfVec2 a, btfVec2 b) { return a.x * b.x + a.y * b.y; }
float dot(btfVec4 a, btfVec4 b) { return a.x * b.x + a.y * b.y + a.z * b.z + a.w * b.w; }
float length(btfVec2 a) { return sqrt(a.x * a.x + a.y * a.y); }
btfVec2 floor(btfVec2 a) { return btfVec2(floor(a.x), floor(a.y)); }
btfVec4 floor(btfVec4 a) { return btfVec4(floor(a.x), floor(a.y), floor(a.z), floor(a.w)); }
btfVec4 mix(btfVec4 a, btfVec4 b, float t) { return a * (1.0 - t) + b * t; }
btfIVec2 clamp(btfIVec2 a, btfIVec2 lo, btfIVec2 hi) { return btfIVec2(clamp(a.x, lo.x, hi.x), clamp(a.y, lo.y, hi.y)); }
// Comparisons give 0/1 components (GLSL's bvecN, converted where the core converts them).
btfIVec2 greaterThanEqual(btfIVec2 a, btfIVec2 b) { return btfIVec2(a.x >= b.x, a.y >= b.y); }
btfIVec2 lessThan(btfIVec2 a, btfIVec2 b) { return btfIVec2(a.x < b.x, a.y < b.y); }
btfIVec4 greaterThan(btfIVec4 a, btfIVec4 b) { return btfIVec4(a.x > b.x, a.y > b.y, a.z > b.z, a.w > b.w); }
vector greaterThan(vector a, vector b) { return vector(a[0] > b[0], a[1] > b[1], a[2] > b[2]); }
int all(btfIVec2 a) { return a.x != 0 && a.y != 0; }

// textureSize(sampler, 0) and texelFetch(sampler, ivec2(x, row from the bottom), 0) on a file.
btfIVec2 btfTextureSize(string file, int lod)
{
    int resolution[2] = {0, 0};
    gettextureinfo(file, "resolution", resolution);
    return btfIVec2(resolution[0], resolution[1]);
}

btfVec4 btfTexelFetch(string file, btfIVec2 at, int lod)
{
    btfIVec2 size = btfTextureSize(file, 0);
    float alpha = 0.0;
    // OSL's t runs down the image: row y from the bottom is image row size.y - 1 - y.
    color rgb = texture(file, (at.x + 0.5) / size.x, (size.y - at.y - 0.5) / size.y, 0.0, 0.0, 0.0, 0.0,
                        "interp", "closest", "wrap", "clamp", "alpha", alpha);
    return btfVec4(rgb[0], rgb[1], rgb[2], alpha);
}
