/* Tet mesh files: Gmsh MSH 4.1 ASCII (read and write) and 2.2 ASCII (read), VTK XML
 * unstructured grid .vtu (write, for ParaView).
 *
 * Regions travel as Gmsh physical tags: physical tag = region + 1 (Gmsh tags start at 1).
 * Reading validates the mesh: a degenerate or inverted tet, a node no tet uses, a boundary
 * that is not closed and manifold, overlapping tets or separate solid parts (mesh_check.h) is
 * an error naming the element or node, not a crash. Only a regular file of at most
 * NS_LIMIT_MESH_FILE_BYTES (ns_limits.h) is read (file_in.h). */
#ifndef NS_MESH_IO_H
#define NS_MESH_IO_H

#include "mesh.h"

/* Reads path into m, which the call initialises (do not pass a mesh that holds data). Returns 0, or
 * -1 with "path:line: message" in err. Only tetrahedra (Gmsh element type 4) make the mesh; points,
 * lines and triangles in the file are skipped. Tets without a physical tag get region 0. */
int ns_mesh_read_msh(const char *path, NsMesh *m, char *err, int err_sz);

/* Writes MSH 4.1 ASCII. names (may be NULL) gives $PhysicalNames for regions
 * 0..name_count-1. The mesh must be compact (ns_mesh_compact). Writes to a temporary file and
 * renames it, so a failed write leaves no partial file. Returns 0, or -1 with a message. */
int ns_mesh_write_msh(const char *path, const NsMesh *m, const char *const *names, int name_count,
                      char *err, int err_sz);

/* Writes a .vtu with point data "fixed" and cell data "region" and "quality" (material space).
 * Same atomicity and compactness rules. */
int ns_mesh_write_vtu(const char *path, const NsMesh *m, char *err, int err_sz);

#endif
