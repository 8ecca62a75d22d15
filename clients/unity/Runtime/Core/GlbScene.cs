using System;
using System.Collections.Generic;
using System.Globalization;
using System.Text;

namespace Vista.Client
{
    /// <summary>
    /// What a headset needs from the JSON chunk of scene.glb, read without a glTF importer:
    /// the data (<c>extras</c>) of each defect node <c>defect-&lt;id&gt;</c>, the scene pose of each
    /// image-marker anchor node <c>marker-&lt;name&gt;</c>, and the asset's extras (scene ETag,
    /// units). Poses are in glTF's frame (metres, +Y up, right-handed), composed down the node
    /// hierarchy.
    /// </summary>
    public sealed class GlbScene
    {
        const uint GlbMagic = 0x46546C67;
        const uint JsonChunk = 0x4E4F534A;
        const int HeaderBytes = 12;
        const int ChunkHeaderBytes = 8;

        /// <summary>Name prefix of the defect nodes.</summary>
        public const string DefectPrefix = "defect-";

        /// <summary>Name prefix of the image-marker anchor nodes.</summary>
        public const string MarkerPrefix = "marker-";

        readonly Dictionary<long, Dictionary<string, object>> defectExtras = new Dictionary<long, Dictionary<string, object>>();
        readonly Dictionary<string, Pose> markerAnchors = new Dictionary<string, Pose>();

        GlbScene(Dictionary<string, object> document)
        {
            Dictionary<string, object> asset = document.GetObject("asset");
            AssetExtras = (asset == null ? null : asset.GetObject("extras")) ?? new Dictionary<string, object>();
            ReadNodes(document.GetObjects("nodes"));
        }

        /// <summary><c>asset.extras</c>: units, up axis, <c>scene_etag</c>, <c>inspection_id</c>, …</summary>
        public Dictionary<string, object> AssetExtras { get; private set; }

        /// <summary>The <c>extras</c> of each defect node, by defect id (type, value, unit,
        /// σ, location, extent; the status, severity and consensus come with the sync).</summary>
        public IReadOnlyDictionary<long, Dictionary<string, object>> DefectExtras
        {
            get { return defectExtras; }
        }

        /// <summary>The scene pose of each image marker's anchor node, by marker name.</summary>
        public IReadOnlyDictionary<string, Pose> MarkerAnchors
        {
            get { return markerAnchors; }
        }

        /// <summary>Reads a binary glTF 2.0 file; throws <see cref="FormatException"/> when it is
        /// not one.</summary>
        public static GlbScene Parse(byte[] glb)
        {
            return new GlbScene(JsonChunkOf(glb));
        }

        /// <summary>The glTF document of a binary glTF 2.0 file (its JSON chunk); throws
        /// <see cref="FormatException"/> when it is not one.</summary>
        public static Dictionary<string, object> JsonChunkOf(byte[] glb)
        {
            if (glb == null || glb.Length < HeaderBytes + ChunkHeaderBytes)
            {
                throw new FormatException("GLB: too short for a binary glTF file");
            }
            if (UInt32At(glb, 0) != GlbMagic || UInt32At(glb, 4) != 2)
            {
                throw new FormatException("GLB: not a binary glTF 2.0 file");
            }
            long declared = UInt32At(glb, 8);
            long jsonLength = UInt32At(glb, HeaderBytes);
            if (declared > glb.Length || HeaderBytes + ChunkHeaderBytes + jsonLength > declared)
            {
                throw new FormatException("GLB: the file is truncated");
            }
            if (UInt32At(glb, HeaderBytes + 4) != JsonChunk)
            {
                throw new FormatException("GLB: the first chunk is not JSON");
            }
            string json = Encoding.UTF8.GetString(glb, HeaderBytes + ChunkHeaderBytes, (int)jsonLength);
            return Json.ParseObject(json);
        }

        static uint UInt32At(byte[] bytes, int offset)
        {
            return (uint)(bytes[offset] | bytes[offset + 1] << 8 | bytes[offset + 2] << 16 | bytes[offset + 3] << 24);
        }

        void ReadNodes(List<Dictionary<string, object>> nodes)
        {
            var parents = new int[nodes.Count];
            for (int i = 0; i < parents.Length; i++)
            {
                parents[i] = -1;
            }
            for (int i = 0; i < nodes.Count; i++)
            {
                foreach (object child in nodes[i].GetArray("children"))
                {
                    if (!(child is long) || (long)child < 0 || (long)child >= nodes.Count || parents[(long)child] >= 0)
                    {
                        throw new FormatException("glTF: node " + i + " has a bad child " + child);
                    }
                    parents[(long)child] = i;
                }
            }
            var global = new Matrix4[nodes.Count];
            for (int i = 0; i < nodes.Count; i++)
            {
                string name = nodes[i].GetString("name") ?? "";
                long defectId;
                if (name.StartsWith(DefectPrefix, StringComparison.Ordinal)
                    && long.TryParse(name.Substring(DefectPrefix.Length), NumberStyles.None, CultureInfo.InvariantCulture, out defectId))
                {
                    defectExtras[defectId] = nodes[i].GetObject("extras") ?? new Dictionary<string, object>();
                }
                else if (name.StartsWith(MarkerPrefix, StringComparison.Ordinal))
                {
                    markerAnchors[name.Substring(MarkerPrefix.Length)] = Pose.FromMatrix(GlobalOf(i, nodes, parents, global, 0));
                }
            }
        }

        /// <summary>A node's transform in the scene: its parents' transforms times its own.</summary>
        static Matrix4 GlobalOf(int node, List<Dictionary<string, object>> nodes, int[] parents, Matrix4[] global, int depth)
        {
            if (global[node] != null)
            {
                return global[node];
            }
            if (depth > nodes.Count)
            {
                throw new FormatException("glTF: the node hierarchy has a cycle");
            }
            Matrix4 local = LocalOf(nodes[node]);
            global[node] = parents[node] < 0 ? local : GlobalOf(parents[node], nodes, parents, global, depth + 1) * local;
            return global[node];
        }

        static Matrix4 LocalOf(Dictionary<string, object> node)
        {
            double[] matrix = node.GetDoubles("matrix");
            if (matrix != null)
            {
                return Matrix4.FromColumnMajor(matrix);
            }
            Pose pose = Pose.FromGltf(node.GetDoubles("translation"), node.GetDoubles("rotation"));
            double[] scale = node.GetDoubles("scale") ?? new double[] { 1, 1, 1 };
            if (scale.Length != 3)
            {
                throw new FormatException("glTF: a node's scale has 3 numbers");
            }
            return pose.ToMatrix() * Matrix4.Scaling(scale[0], scale[1], scale[2]);
        }
    }
}
