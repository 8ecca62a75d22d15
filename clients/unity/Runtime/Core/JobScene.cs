using System;
using System.Collections.Generic;
using System.Linq;

namespace Vista.Client
{
    /// <summary>
    /// What a headset needs from a job's scene (<c>GET /jobs/{id}/scene.glb</c>: a trajectory,
    /// depth clouds, a track through a LiDAR drive), read from its JSON chunk without a glTF
    /// importer: the root node <c>job-&lt;id&gt;</c> and its extras (the job's kind and the run's
    /// figures), the names of the nodes under it, the frame length and the animation
    /// <c>frames</c> (how many keys each animated node has, how long it runs). glTFast plays
    /// the animation itself; this is what the client shows beside it.
    /// </summary>
    public sealed class JobScene
    {
        /// <summary>Name prefix of a job scene's root node.</summary>
        public const string RootPrefix = "job-";

        JobScene(Dictionary<string, object> document)
        {
            Dictionary<string, object> asset = document.GetObject("asset");
            AssetExtras = (asset == null ? null : asset.GetObject("extras")) ?? new Dictionary<string, object>();
            List<Dictionary<string, object>> nodes = document.GetObjects("nodes");
            if (nodes.Count == 0 || !(nodes[0].GetString("name") ?? "").StartsWith(RootPrefix, StringComparison.Ordinal))
            {
                throw new FormatException("glTF: not a job scene (its first node is not job-<id>)");
            }
            RootExtras = nodes[0].GetObject("extras") ?? new Dictionary<string, object>();
            NodeNames = nodes.Select(n => n.GetString("name") ?? "").ToList();
            FrameSeconds = AssetExtras.ContainsKey("frame_s") ? AssetExtras.GetDouble("frame_s") : 0;
            ReadAnimation(document, nodes);
        }

        /// <summary><c>asset.extras</c>: units, up axis, the frame it was converted from, job id, kind.</summary>
        public Dictionary<string, object> AssetExtras { get; private set; }

        /// <summary>The root node's extras: job id, kind, step and the run's <c>figures</c>.</summary>
        public Dictionary<string, object> RootExtras { get; private set; }

        /// <summary>Every node's name, in the file's order (the root first).</summary>
        public List<string> NodeNames { get; private set; }

        /// <summary>How long one frame of a drive is shown (seconds).</summary>
        public double FrameSeconds { get; private set; }

        /// <summary>Keys of the animation <c>frames</c> per animated node name (empty: none).</summary>
        public Dictionary<string, int> KeysByNode { get; private set; }

        /// <summary>The animation's length in seconds (0: no animation).</summary>
        public double DurationSeconds { get; private set; }

        /// <summary>Reads a job's scene.glb; throws <see cref="FormatException"/> when it is not one.</summary>
        public static JobScene Parse(byte[] glb)
        {
            return new JobScene(GlbScene.JsonChunkOf(glb));
        }

        void ReadAnimation(Dictionary<string, object> document, List<Dictionary<string, object>> nodes)
        {
            KeysByNode = new Dictionary<string, int>();
            List<Dictionary<string, object>> accessors = document.GetObjects("accessors");
            foreach (Dictionary<string, object> animation in document.GetObjects("animations"))
            {
                List<Dictionary<string, object>> samplers = animation.GetObjects("samplers");
                foreach (Dictionary<string, object> channel in animation.GetObjects("channels"))
                {
                    int node = (int)channel.GetObject("target").GetInt64("node");
                    Dictionary<string, object> times = accessors[(int)samplers[(int)channel.GetInt64("sampler")].GetInt64("input")];
                    string name = nodes[node].GetString("name") ?? "";
                    int known;
                    KeysByNode[name] = Math.Max(KeysByNode.TryGetValue(name, out known) ? known : 0, (int)times.GetInt64("count"));
                    double[] last = times.GetDoubles("max");
                    DurationSeconds = Math.Max(DurationSeconds, last == null ? 0 : last[0]);
                }
            }
        }
    }
}
