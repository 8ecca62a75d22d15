using System;
using System.Collections.Generic;
using System.Linq;
using UnityEngine;
using UnityEngine.UI;

namespace Vista.Client.Unity
{
    /// <summary>
    /// The panel of the selected defect: what it is, what everyone thinks of it, and four
    /// buttons (confirm, reject, reclassify as the type picked, uncertain) with a comment
    /// field. A judgment shows at once and is pushed when the network allows
    /// (<see cref="VistaClientBehaviour.Judge"/>). Voice commands or MRTK buttons can call
    /// the public methods instead of the uGUI buttons.
    /// </summary>
    public sealed class JudgmentPanel : MonoBehaviour
    {
        [SerializeField] VistaClientBehaviour client;
        [SerializeField] Text heading;
        [SerializeField] Text details;
        [SerializeField] InputField comment;
        [SerializeField] Dropdown newType;
        [SerializeField] Button confirmButton;
        [SerializeField] Button rejectButton;
        [SerializeField] Button reclassifyButton;
        [SerializeField] Button uncertainButton;

        long? defectId;
        string notice;

        void Awake()
        {
            newType.ClearOptions();
            newType.AddOptions(DefectTypes.All.ToList());
            confirmButton.onClick.AddListener(Confirm);
            rejectButton.onClick.AddListener(Reject);
            reclassifyButton.onClick.AddListener(Reclassify);
            uncertainButton.onClick.AddListener(Uncertain);
        }

        void OnEnable()
        {
            client.StatusChanged += Render;
            Render();
        }

        void OnDisable()
        {
            client.StatusChanged -= Render;
        }

        /// <summary>Shows a defect (null: none; the buttons do nothing).</summary>
        public void Show(long? id)
        {
            defectId = id;
            notice = null;
            Render();
        }

        /// <summary>The defect is real.</summary>
        public void Confirm() => Submit(Verdicts.Confirmed, null);

        /// <summary>The defect is not real.</summary>
        public void Reject() => Submit(Verdicts.Rejected, null);

        /// <summary>The defect is real but of the type picked in the menu.</summary>
        public void Reclassify() => Submit(Verdicts.Reclassified, DefectTypes.All[newType.value]);

        /// <summary>Cannot tell.</summary>
        public void Uncertain() => Submit(Verdicts.Uncertain, null);

        void Submit(string verdict, string type)
        {
            Defect defect = Selected();
            if (defect == null)
            {
                return;
            }
            if (type != null && type == defect.Type)
            {
                notice = $"It already is a {type}: pick another type to reclassify it.";
                Render();
                return;
            }
            try
            {
                client.Judge(defect.Id, verdict, type, comment.text);
                comment.text = "";
                notice = null;
            }
            catch (ArgumentException refused)
            {
                notice = refused.Message;
            }
            Render();
        }

        Defect Selected()
        {
            return defectId.HasValue && client.Sync.Defects.TryGetValue(defectId.Value, out Defect defect) ? defect : null;
        }

        void Render()
        {
            Defect defect = Selected();
            bool shown = defect != null;
            confirmButton.interactable = rejectButton.interactable = shown;
            reclassifyButton.interactable = uncertainButton.interactable = shown;
            if (!shown)
            {
                heading.text = "No defect selected";
                details.text = notice ?? "";
                return;
            }
            string judged = defect.ToleranceState == "uncertain" ? "uncertain (within 2σ)" : defect.Severity;
            heading.text = $"Defect {defect.Id} · {defect.Type} · {judged}";
            details.text = string.Join("\n", Lines(defect));
        }

        IEnumerable<string> Lines(Defect defect)
        {
            if (notice != null)
            {
                yield return notice;
            }
            Consensus consensus = client.Sync.ConsensusOf(defect.Id);
            yield return consensus == null
                ? "Nobody judged it yet."
                : $"{consensus.Total} judgment(s), majority {consensus.Majority ?? "none"}, agreement {consensus.Agreement:P0}"
                    + (consensus.NeedsReview ? ", needs review" : "");
            bool pending = client.Sync.Outbox.Any(item => item.DefectId == defect.Id);
            foreach (Judgment judgment in client.Sync.JudgmentsOf(defect.Id))
            {
                bool mine = client.Sync.User != null && judgment.UserId == client.Sync.User.Id;
                string who = mine ? "You" : judgment.Username;
                string verdict = judgment.NewType == null ? judgment.Verdict : $"{judgment.Verdict} as {judgment.NewType}";
                string state = mine && pending ? " (not sent yet)" : "";
                string remark = string.IsNullOrEmpty(judgment.Comment) ? "" : $": {judgment.Comment}";
                yield return $"{who}: {verdict}{state}{remark}";
            }
        }
    }
}
