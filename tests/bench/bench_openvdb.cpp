/*
 * bench_openvdb: OpenVDB's mesh-to-volume on a triangle dump written by
 * bench_voxel --dump, as the peer of algo/refine/voxel.c.
 *
 *   bench_openvdb FILE.tri --depth D [--repeat 5] [--threads 0] [--band 1]
 *
 * The grid matches bench_voxel's: voxel size = the largest MBR extent / 2^D,
 * voxel (0,0,0) centred half a voxel inside the MBR's min corner, so that
 * voxel (i,j,k) is the cell of the same index along the longest axis. The
 * models are not watertight, so the volume is an unsigned distance field
 * (tools::meshToUnsignedDistanceField) with a narrow band of --band voxels
 * (default 1: the voxels within one voxel of a triangle). --threads 1 caps
 * TBB at one thread (tbb::global_control); 0 leaves OpenVDB's default, one
 * per core. Times (wall clock, the conversion only: the mesh is already in
 * OpenVDB's arrays, as our voxel_mark gets it) are the median and minimum of
 * --repeat runs after one warm-up; prints one JSON object.
 */
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include <openvdb/openvdb.h>
#include <openvdb/tools/MeshToVolume.h>
#include <tbb/global_control.h>

static uint32_t get_u32(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static float get_f32(const unsigned char *p)
{
    uint32_t u = get_u32(p);
    float f;
    std::memcpy(&f, &u, 4);
    return f;
}

int main(int argc, char **argv)
{
    const char *path = nullptr;
    int depth = -1, repeat = 5, threads = 0;
    float band = 1.0f;
    for (int i = 1; i < argc; i++) {
        std::string a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : nullptr;
        if (a == "--depth" && v)
            depth = std::atoi(v), i++;
        else if (a == "--repeat" && v)
            repeat = std::atoi(v), i++;
        else if (a == "--threads" && v)
            threads = std::atoi(v), i++;
        else if (a == "--band" && v)
            band = (float)std::atof(v), i++;
        else if (!path && a[0] != '-')
            path = argv[i];
        else
            path = nullptr, depth = -1, i = argc;
    }
    if (!path || depth < 1 || depth > 12 || repeat < 1 || threads < 0 || !(band > 0.0f)) {
        std::fprintf(stderr, "usage: bench_openvdb FILE.tri --depth D [--repeat 5] [--threads 0] [--band 1]\n");
        return 2;
    }

    FILE *f = std::fopen(path, "rb");
    if (!f) {
        std::perror(path);
        return 2;
    }
    unsigned char head[8 + 4 + 24];
    if (std::fread(head, 1, sizeof head, f) != sizeof head || std::memcmp(head, "CVRETRI1", 8) != 0) {
        std::fprintf(stderr, "%s: not a bench_voxel dump\n", path);
        return 2;
    }
    uint32_t ntris = get_u32(head + 8);
    float lo[3], hi[3];
    for (int a = 0; a < 3; a++) {
        lo[a] = get_f32(head + 12 + 4 * a);
        hi[a] = get_f32(head + 24 + 4 * a);
    }
    std::vector<unsigned char> raw((size_t)ntris * 36);
    if (std::fread(raw.data(), 1, raw.size(), f) != raw.size()) {
        std::fprintf(stderr, "%s: truncated\n", path);
        return 2;
    }
    std::fclose(f);

    /* Three points per triangle, as the dump has them: the conversion's
     * work is per triangle, and sharing vertices would not change it. */
    std::vector<openvdb::Vec3s> points((size_t)ntris * 3);
    std::vector<openvdb::Vec3I> tris(ntris);
    for (size_t i = 0; i < points.size(); i++)
        points[i] = openvdb::Vec3s(get_f32(&raw[12 * i]), get_f32(&raw[12 * i + 4]), get_f32(&raw[12 * i + 8]));
    for (uint32_t t = 0; t < ntris; t++)
        tris[t] = openvdb::Vec3I(3 * t, 3 * t + 1, 3 * t + 2);
    std::vector<openvdb::Vec4I> quads;

    openvdb::initialize();
    double extent = std::max({(double)hi[0] - lo[0], (double)hi[1] - lo[1], (double)hi[2] - lo[2]});
    double vs = extent / (double)(1u << depth);
    openvdb::math::Transform::Ptr xform = openvdb::math::Transform::createLinearTransform(vs);
    xform->postTranslate(openvdb::Vec3d(lo[0] + 0.5 * vs, lo[1] + 0.5 * vs, lo[2] + 0.5 * vs));

    std::unique_ptr<tbb::global_control> cap;
    if (threads > 0)
        cap.reset(new tbb::global_control(tbb::global_control::max_allowed_parallelism, (size_t)threads));

    std::vector<double> ms;
    openvdb::Index64 active = 0;
    openvdb::Index64 bytes = 0;
    for (int r = -1; r < repeat; r++) { /* r = -1: warm-up (TBB's thread pool, page faults) */
        auto t0 = std::chrono::steady_clock::now();
        openvdb::FloatGrid::Ptr grid =
            openvdb::tools::meshToUnsignedDistanceField<openvdb::FloatGrid>(*xform, points, tris, quads, band);
        auto t1 = std::chrono::steady_clock::now();
        if (r >= 0)
            ms.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
        active = grid->activeVoxelCount();
        bytes = grid->memUsage();
    }
    std::sort(ms.begin(), ms.end());
    std::printf("{\"triangles\": %u, \"depth\": %d, \"threads\": %d, \"band\": %g, \"voxel\": %.9g, "
                "\"ms\": %.4f, \"ms_min\": %.4f, \"active\": %llu, \"mb\": %.3f}\n",
                ntris, depth, threads, (double)band, vs, ms[ms.size() / 2], ms[0], (unsigned long long)active,
                (double)bytes / (1024.0 * 1024.0));
    return 0;
}
